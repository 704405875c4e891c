//! The MAVLink link to the autopilot: connection strings ([`connection`]), the pure mapping
//! between MAVLink messages and runtime types ([`mapping`]), and the link itself ([`link`]):
//! telemetry in, commands out, link-loss detection and failsafe, and the lockstep handshake the
//! simulator uses to stay deterministic; a `tcpout` connection that goes is dialled again
//! ([`redial`]).

pub mod connection;
#[allow(clippy::module_inception)]
pub mod link;
pub mod mapping;
pub mod redial;
pub mod timesync;

pub use connection::{ConnectionSpec, Incoming, ReplayFeed};
pub use link::{
    FailsafeAction, LinkCapture, LinkConfig, LinkStats, LinkStatus, LinkUpdate, MavlinkLink, Sent,
    GIMBAL_COMPONENT_ID,
};
pub use mapping::{
    AckResult, AutopilotKind, AutopilotMode, AutopilotStatus, CommandAck, VehicleCommand,
};
pub use timesync::{ClockSync, ClockSyncStats};

/// What can go wrong with the link.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("bad MAVLink connection string {input:?}: {why}")]
    BadConnectionString { input: String, why: String },
    #[error(
        "bad MAVLink connection string {input:?}: the {field} {text:?} is not a number \
         ({source}); expected {expected}"
    )]
    NotANumber {
        input: String,
        /// `port` or `baud rate`.
        field: &'static str,
        text: String,
        expected: String,
        source: std::num::ParseIntError,
    },
    #[error("cannot open MAVLink connection {spec}: {source}")]
    Open {
        spec: String,
        #[source]
        source: std::io::Error,
    },
    #[error("MAVLink I/O error: {0}")]
    Io(#[from] std::io::Error),
    #[error(
        "lockstep: no TIMESYNC from the simulated autopilot for t = {t_ns} ns within {timeout_s} s \
         (is the simulator running and sending to this link's port?)"
    )]
    LockstepTimeout { t_ns: u64, timeout_s: f64 },
    #[error(
        "lockstep: expected the autopilot's TIMESYNC for t = {expected_ns} ns, got {got_ns} ns"
    )]
    LockstepOutOfStep { expected_ns: u64, got_ns: u64 },
}
