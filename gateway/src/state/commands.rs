//! Commands to the analysis (acknowledge alarms, reset a driveline's wear), from
//! whoever may give them (the HMI Modbus server, the PLC through it, a local call):
//! a bounded channel the analysis task selects on beside the samples, so a command
//! takes effect at once, in order with the bites, whatever the number of drivelines.

use std::net::SocketAddr;

use tokio::sync::mpsc;

/// Commands in flight to the analysis. A client that writes faster than the analysis
/// applies them gets "busy" (Modbus exception 06) rather than an unbounded queue.
pub const COMMAND_QUEUE: usize = 64;

/// Who gave a command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandOrigin {
    /// A Modbus client of the gateway's server at the PLC's address
    /// (`outputs.plc.address`): the PLC program.
    Plc(SocketAddr),
    /// Any other Modbus client of the gateway's server: an HMI.
    Hmi(SocketAddr),
    /// A call in this process (tests, tools): no client.
    Local,
    /// A client of the OPC UA server (its acknowledge method); its address when the
    /// connection came through the server's listener.
    OpcUa(Option<SocketAddr>),
    /// A client of the maintenance page's API (`POST /api/captures`, with
    /// `outputs.web.allow_commands`), its address.
    Web(SocketAddr),
}

impl CommandOrigin {
    /// `plc`, `hmi`, `local`, `opcua` or `web`, as stored.
    pub fn name(self) -> &'static str {
        match self {
            CommandOrigin::Plc(_) => "plc",
            CommandOrigin::Hmi(_) => "hmi",
            CommandOrigin::Local => "local",
            CommandOrigin::OpcUa(_) => "opcua",
            CommandOrigin::Web(_) => "web",
        }
    }

    /// The client's address, when a client sent it.
    pub fn peer(self) -> Option<SocketAddr> {
        match self {
            CommandOrigin::Plc(peer) | CommandOrigin::Hmi(peer) | CommandOrigin::Web(peer) => {
                Some(peer)
            }
            CommandOrigin::Local => None,
            CommandOrigin::OpcUa(peer) => peer,
        }
    }
}

/// What a command asks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// Clear every latched alarm (TAF, gap, chatter).
    AcknowledgeAlarms {
        /// Who.
        origin: CommandOrigin,
    },
    /// Forget driveline `driveline`'s wear trend and gap estimate (after its coupling was
    /// replaced): the next bite's wear index seeds the trend afresh and its gap pool
    /// starts empty. The gap alarm stays latched until acknowledged.
    ResetWear {
        /// The driveline, index in config order.
        driveline: usize,
        /// Who.
        origin: CommandOrigin,
    },
    /// Start component `component` of driveline `driveline`'s fatigue ledger afresh
    /// (it was replaced): its life used 0 from now, the reset recorded.
    ResetFatigue {
        /// The driveline, index in config order.
        driveline: usize,
        /// The component, index in `drivelines[].fatigue.components`.
        component: usize,
        /// Who.
        origin: CommandOrigin,
    },
    /// Keep the next `seconds` s of driveline `driveline`'s torque as a capture of
    /// kind `manual` (with captures kept: `[history]`).
    CaptureTorque {
        /// The driveline, index in config order.
        driveline: usize,
        /// How long, s (1..=255).
        seconds: u16,
        /// Who.
        origin: CommandOrigin,
    },
    /// Keep the next `seconds` s of every stand of tandem mill `mill` as a capture of
    /// kind `manual` (with captures kept: `[history]`).
    CaptureStands {
        /// The tandem mill, index in config order.
        mill: usize,
        /// How long, s (1..=255).
        seconds: u16,
        /// Who.
        origin: CommandOrigin,
    },
}

/// Why a command was not taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum CommandRefused {
    /// [`COMMAND_QUEUE`] commands are waiting for the analysis: try again.
    #[error("the analysis has {COMMAND_QUEUE} commands waiting; try again")]
    Busy,
    /// The analysis has stopped: the gateway is shutting down.
    #[error("the analysis has stopped")]
    Stopped,
}

/// The sending end, cheap to clone.
#[derive(Debug, Clone)]
pub struct CommandSender(mpsc::Sender<Command>);

/// The receiving end, for the analysis task.
pub type CommandReceiver = mpsc::Receiver<Command>;

/// A command channel of [`COMMAND_QUEUE`] places.
pub fn channel() -> (CommandSender, CommandReceiver) {
    let (sender, receiver) = mpsc::channel(COMMAND_QUEUE);
    (CommandSender(sender), receiver)
}

impl CommandSender {
    /// Hand `command` to the analysis without waiting.
    pub fn send(&self, command: Command) -> Result<(), CommandRefused> {
        self.0.try_send(command).map_err(|error| match error {
            mpsc::error::TrySendError::Full(_) => CommandRefused::Busy,
            mpsc::error::TrySendError::Closed(_) => CommandRefused::Stopped,
        })
    }
}
