//! Dialling a `tcpout` link again when its connection goes: an autopilot's TCP server that
//! restarted (a SITL relaunched, a MAVLink router reset) resets or closes the runtime's
//! connection, and without a new one the vehicle is never heard from again. The dial runs on
//! its own thread, because a connect to an unreachable host blocks for minutes and the
//! mission's loop must not; until a dial succeeds the link is lost as any silent link is, and
//! its failsafe flies the vehicle.

use super::connection::{ConnectionSpec, Transport};
use super::LinkError;
use std::io::{self, ErrorKind};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How long after a failed dial the next one starts.
pub const REDIAL_PERIOD: Duration = Duration::from_secs(1);

/// Whether a stream's send or receive failed because its connection is gone (reset, closed,
/// broken), not for want of data.
pub fn connection_gone(error: &io::Error) -> bool {
    matches!(
        error.kind(),
        ErrorKind::ConnectionReset
            | ErrorKind::ConnectionAborted
            | ErrorKind::BrokenPipe
            | ErrorKind::NotConnected
            | ErrorKind::UnexpectedEof
    )
}

enum State {
    /// The connection works (as far as anyone knows).
    Connected,
    /// Gone: the next dial starts at this instant.
    DialAt(Instant),
    Dialing(JoinHandle<Result<Transport, LinkError>>),
}

/// The re-dialling of one `tcpout` connection.
pub struct Redial {
    spec: ConnectionSpec,
    signing_key: Option<[u8; 32]>,
    state: State,
}

impl Redial {
    /// For a link opened on `spec`: `None` unless it is one that can be dialled again (TCP).
    pub fn of(spec: &ConnectionSpec, signing_key: Option<[u8; 32]>) -> Option<Self> {
        matches!(spec, ConnectionSpec::TcpOut { .. }).then(|| Self {
            spec: spec.clone(),
            signing_key,
            state: State::Connected,
        })
    }

    /// The connection was found gone: dial at once, unless a dial is already due or running.
    pub fn connection_lost(&mut self) {
        if matches!(self.state, State::Connected) {
            tracing::warn!(link = %self.spec, "MAVLink connection gone: dialling again");
            self.state = State::DialAt(Instant::now());
        }
    }

    /// A new transport when a dial succeeded since the last call; starts the next dial when
    /// one is due. Never blocks.
    pub fn poll(&mut self) -> Option<Transport> {
        let now = Instant::now();
        match &self.state {
            State::Dialing(dial) if dial.is_finished() => {
                let State::Dialing(dial) = std::mem::replace(&mut self.state, State::Connected)
                else {
                    unreachable!("matched as dialling above");
                };
                match dial.join() {
                    Ok(Ok(transport)) => {
                        tracing::info!(link = %self.spec, "MAVLink connection dialled again");
                        return Some(transport);
                    }
                    Ok(Err(error)) => {
                        tracing::debug!(%error, "MAVLink dial failed; trying again");
                    }
                    Err(_) => tracing::warn!(link = %self.spec, "the MAVLink dial's thread died"),
                }
                self.state = State::DialAt(now + REDIAL_PERIOD);
            }
            State::DialAt(at) if now >= *at => {
                let (spec, key) = (self.spec.clone(), self.signing_key);
                match std::thread::Builder::new()
                    .name("qosrt-mavlink-dial".into())
                    .spawn(move || spec.open(key))
                {
                    Ok(dial) => self.state = State::Dialing(dial),
                    Err(error) => {
                        tracing::warn!(%error, "cannot start the MAVLink dial's thread");
                        self.state = State::DialAt(now + REDIAL_PERIOD);
                    }
                }
            }
            _ => {}
        }
        None
    }
}
