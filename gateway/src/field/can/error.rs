//! [`CanError`]: why a CAN reader could not start or stopped.

use std::io;

/// Why a CAN reader could not start or stopped.
#[derive(Debug, thiserror::Error)]
pub enum CanError {
    /// The configuration has no CAN source with this index.
    #[error("no CAN source with index {index}: the configuration has {count}")]
    NoSuchSource {
        /// The index asked for.
        index: usize,
        /// CAN sources in the configuration.
        count: usize,
    },
    /// The running kernel was built without SocketCAN, or the service may not open
    /// `AF_CAN` sockets (a systemd unit's `RestrictAddressFamilies=` without it):
    /// `socket(AF_CAN)` gives errno 97 either way.
    #[error(
        "SocketCAN not available in this kernel (errno 97) for CAN interface `{interface}`, \
         or not to this service (a systemd unit's RestrictAddressFamilies= without AF_CAN); \
         for the tests, run the vcan suite through scripts/uml-vcan"
    )]
    NoSocketCan {
        /// The interface name.
        interface: String,
    },
    /// The kernel has SocketCAN but no interface of that name (errno 19).
    #[error(
        "no such CAN interface `{interface}` (errno 19, ENODEV); create it, e.g. \
         `ip link add dev {interface} type vcan && ip link set up {interface}`"
    )]
    NoSuchInterface {
        /// The interface name.
        interface: String,
    },
    /// Any other failure to open or configure the socket.
    #[error("cannot open CAN interface `{interface}`: {source}")]
    Open {
        /// The interface name.
        interface: String,
        /// Why.
        #[source]
        source: io::Error,
    },
    /// Reading from an open socket failed (e.g. the interface went away).
    #[error("reading CAN interface `{interface}`: {source}")]
    Read {
        /// The interface name.
        interface: String,
        /// Why.
        #[source]
        source: io::Error,
    },
    /// The receiving end of the sample channel was dropped.
    #[error("CAN reader for `{interface}`: the sample channel is closed")]
    SamplesClosed {
        /// The interface name.
        interface: String,
    },
}
