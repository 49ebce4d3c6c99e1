//! The SocketCAN socket: opening an interface (CAN FD raw socket, error frames,
//! `SO_TIMESTAMPNS`, `SO_RXQ_OVFL`, registered with tokio) and reading the queued frames
//! with their control messages in one `recvmmsg` call.

use std::io::{self, IoSliceMut};
use std::os::fd::AsRawFd;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use millgate_config::frame::CANFD_MTU;
use nix::sys::socket::{self as nix_socket, sockopt, ControlMessageOwned, MsgFlags};
use socketcan::{Socket, SocketOptions};
use tokio::io::unix::AsyncFd;
use tokio::io::Interest;

use super::error::CanError;

/// `errno` EAFNOSUPPORT: the kernel has no `AF_CAN` address family.
const EAFNOSUPPORT: i32 = 97;
/// `errno` ENODEV: no network interface of that name.
const ENODEV: i32 = 19;
/// Most frames read by one `recvmmsg` call and decoded into one batch of
/// [`Acquired::Samples`](crate::field::acquired::Acquired::Samples) messages. Its headers are set up for every call (see
/// [`receive_batch`]), so a larger batch costs more per wake-up on a quiet bus; 64
/// already cuts the system calls of a backlog 64-fold.
pub(crate) const MAX_FRAMES_PER_BATCH: usize = 64;

/// The ancillary data that came with one frame.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Received {
    /// Bytes of the frame in its receive buffer.
    len: usize,
    /// `SCM_TIMESTAMPNS`: when the kernel queued the frame.
    pub(crate) kernel_time: Option<SystemTime>,
    /// `SO_RXQ_OVFL`: frames dropped by this socket since it opened.
    pub(crate) drops: Option<u32>,
}

/// Receive buffers for one batch of frames, allocated once per reader.
#[derive(Debug)]
pub(crate) struct ReceiveBuffers {
    /// One `struct canfd_frame` per slot.
    frames: Box<[[u8; CANFD_MTU]; MAX_FRAMES_PER_BATCH]>,
    /// What came with `frames[i]`, for the first `received.len()` slots.
    received: Vec<Received>,
}

impl ReceiveBuffers {
    pub(crate) fn new() -> Self {
        ReceiveBuffers {
            frames: Box::new([[0; CANFD_MTU]; MAX_FRAMES_PER_BATCH]),
            received: Vec::with_capacity(MAX_FRAMES_PER_BATCH),
        }
    }

    /// The frames of the last batch with their ancillary data, in arrival order.
    pub(crate) fn frames(&self) -> impl Iterator<Item = (&[u8], &Received)> + '_ {
        self.frames
            .iter()
            .zip(&self.received)
            .map(|(frame, received)| (frame.get(..received.len).unwrap_or_default(), received))
    }
}

/// Reads the frames queued on non-blocking socket `socket`, up to
/// [`MAX_FRAMES_PER_BATCH`], with their control messages, in one `recvmmsg` call.
///
/// One system call per batch rather than per frame: under User-Mode Linux (where the
/// vcan tests run) and some hypervisors a system call costs tens of microseconds,
/// more than decoding a frame. Fails with `WouldBlock` when no frame is queued;
/// otherwise returns how many were read, fewer than the maximum once the queue is
/// empty.
pub(crate) fn receive_batch(
    socket: &impl AsRawFd,
    buffers: &mut ReceiveBuffers,
) -> io::Result<usize> {
    let ReceiveBuffers { frames, received } = buffers;
    received.clear();
    // The headers hold raw pointers (not `Send`), so they live for this call only
    // and cannot be kept in the reader, which a spawned task owns.
    let control = nix::cmsg_space!(nix::sys::time::TimeSpec, u32);
    let mut headers =
        nix_socket::MultiHeaders::<()>::preallocate(MAX_FRAMES_PER_BATCH, Some(control));
    let mut slices = frames.each_mut().map(|frame| [IoSliceMut::new(frame)]);
    let messages = nix_socket::recvmmsg(
        socket.as_raw_fd(),
        &mut headers,
        slices.iter_mut(),
        MsgFlags::MSG_DONTWAIT,
        None,
    )
    .map_err(io::Error::from)?;
    for message in messages {
        let mut kernel_time = None;
        let mut drops = None;
        for control_message in message.cmsgs().map_err(io::Error::from)? {
            match control_message {
                ControlMessageOwned::ScmTimestampns(time) => {
                    let since_epoch = u64::try_from(time.tv_sec())
                        .ok()
                        .zip(u32::try_from(time.tv_nsec()).ok())
                        .map(|(s, ns)| Duration::new(s, ns));
                    kernel_time = since_epoch
                        .filter(|d| !d.is_zero())
                        .and_then(|d| UNIX_EPOCH.checked_add(d));
                }
                ControlMessageOwned::RxqOvfl(count) => drops = Some(count),
                _ => {}
            }
        }
        received.push(Received {
            len: message.bytes,
            kernel_time,
            drops,
        });
    }
    Ok(received.len())
}

/// Opens `interface` with a non-blocking CAN FD raw socket that also receives error
/// frames, and registers it with the tokio reactor (call within a runtime).
///
/// Kernel receive timestamps (`SO_TIMESTAMPNS`) and drop counts (`SO_RXQ_OVFL`) are
/// asked for; a kernel that refuses either is logged and the socket is used without it
/// (arrival times, no drop count). Fails with [`CanError::NoSocketCan`] on a kernel
/// without SocketCAN and with [`CanError::NoSuchInterface`] when the interface does
/// not exist.
pub(crate) fn open_socket(interface: &str) -> Result<AsyncFd<socketcan::CanFdSocket>, CanError> {
    check_socketcan(interface)?;
    let fail = |error| open_error(interface, error);
    let socket = socketcan::CanFdSocket::open(interface).map_err(fail)?;
    socket.set_nonblocking(true).map_err(fail)?;
    socket.set_error_filter_accept_all().map_err(fail)?;
    if let Err(error) = socket.set_recv_timestamp(true) {
        tracing::warn!(%interface, %error, "no kernel receive timestamps: frames dated on arrival");
    }
    if let Err(error) = nix_socket::setsockopt(&socket, sockopt::RxqOvfl, &1) {
        tracing::warn!(%interface, %error, "no kernel drop count (SO_RXQ_OVFL)");
    }
    // SAFETY: `register_with_interest` asks that the fd stay open and not be
    // replaced while registered. The `CanFdSocket` owns its fd and closes it only
    // when dropped, and the `AsyncFd` owns the socket, deregistering first.
    #[allow(unsafe_code)]
    let socket = unsafe { AsyncFd::register_with_interest(socket, Interest::READABLE) }
        .map_err(|error| fail(error.into_parts().1))?;
    Ok(socket)
}

/// Fails with [`CanError::NoSocketCan`] when the kernel has no `AF_CAN` sockets.
fn check_socketcan(interface: &str) -> Result<(), CanError> {
    let probe = socket2::Socket::new(
        socket2::Domain::from(socketcan::addr::AF_CAN),
        socket2::Type::RAW,
        Some(socket2::Protocol::from(socketcan::addr::CAN_RAW)),
    );
    match probe {
        Ok(_) => Ok(()),
        Err(error) => Err(open_error(interface, error)),
    }
}

/// Names the two errors an operator can act on; keeps the rest as is.
fn open_error(interface: &str, error: io::Error) -> CanError {
    let interface = interface.to_owned();
    match error.raw_os_error() {
        Some(EAFNOSUPPORT) => CanError::NoSocketCan { interface },
        Some(ENODEV) => CanError::NoSuchInterface { interface },
        _ => CanError::Open {
            interface,
            source: error,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errno_names_the_problem() {
        let no_can = open_error("vcan0", io::Error::from_raw_os_error(EAFNOSUPPORT));
        assert!(matches!(no_can, CanError::NoSocketCan { .. }));
        assert!(no_can
            .to_string()
            .contains("SocketCAN not available in this kernel (errno 97)"));
        let no_dev = open_error("can7", io::Error::from_raw_os_error(ENODEV));
        assert!(matches!(no_dev, CanError::NoSuchInterface { .. }));
        assert!(no_dev.to_string().contains("no such CAN interface `can7`"));
        let other = open_error("can0", io::Error::from_raw_os_error(1));
        assert!(matches!(other, CanError::Open { .. }));
    }
}
