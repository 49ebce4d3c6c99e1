//! Cooperative shutdown for the gateway's tasks.

use tokio::sync::watch;

/// Sends the shutdown request to every task holding a [`Shutdown`].
#[derive(Debug)]
pub struct ShutdownTrigger(watch::Sender<bool>);

/// A task's view of the shutdown request.
#[derive(Debug, Clone)]
pub struct Shutdown(watch::Receiver<bool>);

/// A trigger and the first receiver.
pub fn channel() -> (ShutdownTrigger, Shutdown) {
    let (sender, receiver) = watch::channel(false);
    (ShutdownTrigger(sender), Shutdown(receiver))
}

impl ShutdownTrigger {
    /// Ask every task to stop.
    pub fn trigger(&self) {
        self.0.send_replace(true);
    }

    /// Another receiver.
    pub fn subscribe(&self) -> Shutdown {
        Shutdown(self.0.subscribe())
    }
}

impl Shutdown {
    /// Whether shutdown was requested.
    pub(crate) fn is_shutdown(&self) -> bool {
        *self.0.borrow()
    }

    /// Wait until shutdown is requested (at once if it already was, or if the
    /// trigger was dropped).
    pub async fn recv(&mut self) {
        // An error means the trigger is gone: nobody can ask any more, so stop too.
        let _ = self.0.wait_for(|stop| *stop).await;
    }

    /// The underlying receiver, for APIs that take a `watch::Receiver<bool>`.
    pub fn receiver(&self) -> watch::Receiver<bool> {
        self.0.clone()
    }
}
