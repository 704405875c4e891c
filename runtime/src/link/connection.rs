//! Connection strings and the transports behind them.
//!
//! `udpin:HOST:PORT` listens (the usual companion side: PX4 sends to the companion's port,
//! and the link answers the address the autopilot's datagrams come from); `udpout:HOST:PORT`
//! sends to a listening autopilot; `tcpout:HOST:PORT` connects to one (PX4 SITL, ArduPilot
//! SITL's 5760); `serial:/dev/ttyXXX:BAUD` is a telemetry port.
//!
//! UDP is handled here on a plain `UdpSocket`, one datagram at a time, with MAVLink framing and
//! CRC from the `mavlink` crate: that is what lets the link count a garbage datagram (the crate's
//! stream reader silently resynchronises past it), wait with a wall-clock timeout (lockstep) and
//! bind an OS-chosen port. TCP and serial go through `mavlink::connect` (MAVLink 2).

use super::LinkError;
use mavlink::dialects::common::MavMessage;
use mavlink::error::MessageReadError;
use mavlink::{MavConnection, MavHeader, MavlinkVersion, SigningConfig, SigningData};
use std::fmt;
use std::io::{self, ErrorKind};
use std::net::{SocketAddr, ToSocketAddrs, UdpSocket};
use std::time::{Duration, Instant};

/// The schemes a connection string may start with.
pub const SCHEMES: &str = "udpin, udpout, tcpout, serial";
/// Baud rates a serial link may use (what Linux tty drivers and flight controllers support).
pub const BAUD_RATES: [u32; 13] = [
    9_600, 19_200, 38_400, 57_600, 115_200, 230_400, 460_800, 500_000, 921_600, 1_000_000,
    1_500_000, 2_000_000, 3_000_000,
];

/// A parsed connection string.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ConnectionSpec {
    /// Listen on HOST:PORT; port 0 lets the OS choose (see `MavlinkLink::local_addr`).
    UdpIn {
        host: String,
        port: u16,
    },
    /// Send to HOST:PORT from an OS-chosen local port.
    UdpOut {
        host: String,
        port: u16,
    },
    TcpOut {
        host: String,
        port: u16,
    },
    Serial {
        device: String,
        baud: u32,
    },
}

impl fmt::Display for ConnectionSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::UdpIn { host, port } => write!(f, "udpin:{host}:{port}"),
            Self::UdpOut { host, port } => write!(f, "udpout:{host}:{port}"),
            Self::TcpOut { host, port } => write!(f, "tcpout:{host}:{port}"),
            Self::Serial { device, baud } => write!(f, "serial:{device}:{baud}"),
        }
    }
}

impl std::str::FromStr for ConnectionSpec {
    type Err = LinkError;

    fn from_str(input: &str) -> Result<Self, Self::Err> {
        Self::parse(input)
    }
}

impl ConnectionSpec {
    /// Parses `udpin:HOST:PORT`, `udpout:HOST:PORT`, `tcpout:HOST:PORT` or
    /// `serial:DEVICE:BAUD`.
    pub fn parse(input: &str) -> Result<Self, LinkError> {
        let bad = |why: String| LinkError::BadConnectionString {
            input: input.to_string(),
            why,
        };
        let trimmed = input.trim();
        let Some((scheme, rest)) = trimmed.split_once(':') else {
            return Err(bad(format!(
                "expected SCHEME:ADDRESS with SCHEME one of {SCHEMES} \
                 (e.g. udpin:0.0.0.0:14540 or serial:/dev/ttyACM0:921600)"
            )));
        };
        match scheme {
            "udpin" | "udpout" | "tcpout" => {
                let Some((host, port)) = rest.rsplit_once(':') else {
                    return Err(bad(format!("expected {scheme}:HOST:PORT, found no port")));
                };
                // Accept [::1] style IPv6 hosts and strip the brackets for display consistency.
                if host.is_empty() {
                    return Err(bad(format!(
                        "expected {scheme}:HOST:PORT, the host is empty (use 0.0.0.0 to listen on all interfaces)"
                    )));
                }
                if host.contains(char::is_whitespace) {
                    return Err(bad(format!("the host {host:?} contains whitespace")));
                }
                let port = parse_port(input, port, scheme == "udpin")?;
                let host = host.to_string();
                Ok(match scheme {
                    "udpin" => Self::UdpIn { host, port },
                    "udpout" => Self::UdpOut { host, port },
                    _ => Self::TcpOut { host, port },
                })
            }
            "serial" => {
                let Some((device, baud)) = rest.rsplit_once(':') else {
                    return Err(bad(
                        "expected serial:DEVICE:BAUD (e.g. serial:/dev/ttyACM0:921600), found no baud rate"
                            .to_string(),
                    ));
                };
                if device.is_empty() {
                    return Err(bad(
                        "expected serial:DEVICE:BAUD, the device is empty (e.g. /dev/ttyACM0, /dev/ttyTHS1)"
                            .to_string(),
                    ));
                }
                let baud = parse_number(input, "baud rate", baud, || {
                    format!("one of {BAUD_RATES:?}")
                })?;
                if !BAUD_RATES.contains(&baud) {
                    return Err(bad(format!(
                        "the baud rate {baud} is not a standard rate; expected one of {BAUD_RATES:?}"
                    )));
                }
                Ok(Self::Serial {
                    device: device.to_string(),
                    baud,
                })
            }
            other => {
                let hint = match other {
                    "udp" => " (did you mean udpin, to listen, or udpout, to send?)",
                    "tcp" | "tcpin" => " (did you mean tcpout? the link connects to the autopilot)",
                    _ => "",
                };
                Err(bad(format!(
                    "unknown scheme {other:?}; expected one of {SCHEMES}{hint}"
                )))
            }
        }
    }

    /// Opens the connection (MAVLink 2), signing what it sends and checking what it receives
    /// when a signing key is given.
    pub fn open(&self, signing_key: Option<[u8; 32]>) -> Result<Transport, LinkError> {
        let opened = match self {
            Self::UdpIn { host, port } => UdpTransport::listen(&(host.as_str(), *port)),
            Self::UdpOut { host, port } => UdpTransport::send_to(&(host.as_str(), *port)),
            Self::TcpOut { .. } | Self::Serial { .. } => {
                mavlink::connect::<MavMessage>(&self.to_string()).map(|mut connection| {
                    connection.set_protocol_version(MavlinkVersion::V2);
                    connection.setup_signing(signing_key.map(signing_config));
                    Transport::Stream(Box::new(connection))
                })
            }
        };
        let opened = opened.map(|mut transport| {
            if let (Transport::Udp(udp), Some(key)) = (&mut transport, signing_key) {
                udp.signing = Some(SigningData::from_config(signing_config(key)));
            }
            transport
        });
        opened.map_err(|source| LinkError::Open {
            spec: self.to_string(),
            source,
        })
    }
}

/// A number field (`port`, `baud rate`) of connection string `input`; `expected` says what
/// would have been right.
fn parse_number(
    input: &str,
    field: &'static str,
    text: &str,
    expected: impl FnOnce() -> String,
) -> Result<u32, LinkError> {
    text.parse().map_err(|source| LinkError::NotANumber {
        input: input.to_string(),
        field,
        text: text.to_string(),
        expected: expected(),
        source,
    })
}

/// The port of connection string `input`.
fn parse_port(input: &str, port: &str, zero_allowed: bool) -> Result<u16, LinkError> {
    let low = if zero_allowed { 0 } else { 1 };
    let value = parse_number(input, "port", port, || format!("{low}..=65535"))?;
    if value > 65_535 || value < low {
        return Err(LinkError::BadConnectionString {
            input: input.to_string(),
            why: format!("the port {value} is out of range; expected {low}..=65535"),
        });
    }
    Ok(value as u16)
}

/// The signing of a link: sign what goes out (link id 0), accept only signed MAVLink 2.
fn signing_config(key: [u8; 32]) -> SigningConfig {
    SigningConfig::new(key, 0, true, false)
}

/// One batch from a transport.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Incoming {
    pub messages: Vec<(MavHeader, MavMessage)>,
    /// A datagram (UDP) or frame (stream) that held no valid MAVLink message.
    pub malformed: bool,
    /// Messages refused for a missing or wrong signature (UDP with a signing key).
    pub unsigned: usize,
    /// The sender, for UDP.
    pub from: Option<SocketAddr>,
    /// When the link took it, on the runtime's clock (set by the link; a recording keeps it,
    /// so a replay measures the TIMESYNC round trips the flight measured).
    pub received_s: Option<f64>,
}

/// An open connection.
pub enum Transport {
    Udp(UdpTransport),
    Stream(Box<mavlink::Connection<MavMessage>>),
    /// A recording played back (`qosrt replay`): what each step received, in order.
    Replay(ReplayFeed),
}

/// The MAVLink a recorded flight received, handed to the link batch by batch; what the link
/// sends goes nowhere (the recording is not a vehicle).
#[derive(Debug, Clone, Default)]
pub struct ReplayFeed {
    batches: std::sync::Arc<std::sync::Mutex<std::collections::VecDeque<Incoming>>>,
    /// Whether a message sent now would have had somewhere to go: as the recorded link had a
    /// peer from the start (udpout, TCP, serial) or learned it from the autopilot (udpin).
    peer_known: std::sync::Arc<std::sync::atomic::AtomicBool>,
}

impl ReplayFeed {
    /// A feed for a link that had a peer from the start (`peer_known`), or learns it.
    pub fn new(peer_known: bool) -> Self {
        let feed = Self::default();
        feed.peer_known
            .store(peer_known, std::sync::atomic::Ordering::Release);
        feed
    }

    fn peer_known(&self) -> bool {
        self.peer_known.load(std::sync::atomic::Ordering::Acquire)
    }

    /// Queues one recorded batch for the link's next receive.
    pub fn push(&self, incoming: Incoming) {
        self.lock().push_back(incoming);
    }

    /// Batches not yet received.
    pub fn len(&self) -> usize {
        self.lock().len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, std::collections::VecDeque<Incoming>> {
        self.batches
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// The next batch; waiting for one that the recording does not hold (a lockstep barrier
    /// cut off by the end of a truncated file) is an error, not a wait.
    fn receive(&self, wait: Option<Duration>) -> io::Result<Option<Incoming>> {
        match (self.lock().pop_front(), wait) {
            (Some(incoming), _) => Ok(Some(incoming)),
            (None, None) => Ok(None),
            (None, Some(_)) => Err(io::Error::new(
                ErrorKind::UnexpectedEof,
                "the recording holds no more MAVLink for this step",
            )),
        }
    }
}

impl Transport {
    /// The next datagram or message, waiting up to `wait` (`None`: don't wait). `Ok(None)` when
    /// nothing came.
    pub fn receive(&mut self, wait: Option<Duration>) -> io::Result<Option<Incoming>> {
        match self {
            Self::Udp(udp) => udp.receive(wait),
            Self::Replay(feed) => feed.receive(wait),
            Self::Stream(connection) => {
                let deadline = wait.map(|wait| Instant::now() + wait);
                loop {
                    match connection.try_recv() {
                        Ok(message) => {
                            return Ok(Some(Incoming {
                                messages: vec![message],
                                ..Incoming::default()
                            }))
                        }
                        Err(MessageReadError::Parse(_)) => {
                            return Ok(Some(Incoming {
                                malformed: true,
                                ..Incoming::default()
                            }))
                        }
                        Err(MessageReadError::Io(error)) if no_data(&error) => {}
                        Err(MessageReadError::Io(error)) => return Err(error),
                    }
                    match deadline {
                        Some(deadline) if Instant::now() < deadline => {
                            std::thread::sleep(Duration::from_micros(200))
                        }
                        _ => return Ok(None),
                    }
                }
            }
        }
    }

    /// Sends one message; `Ok(false)` when there is no peer yet (udpin before the autopilot
    /// spoke).
    pub fn send(&mut self, header: MavHeader, message: &MavMessage) -> io::Result<bool> {
        match self {
            Self::Udp(udp) => udp.send(header, message),
            // As the recorded udpin link did: nothing goes out before the autopilot is heard.
            Self::Replay(feed) => Ok(feed.peer_known()),
            Self::Stream(connection) => {
                connection
                    .send(&header, message)
                    .map(|_| true)
                    .map_err(|error| match error {
                        mavlink::error::MessageWriteError::Io(error) => error,
                        other => io::Error::other(other.to_string()),
                    })
            }
        }
    }

    /// Whether this is a recording played back.
    pub fn is_replay(&self) -> bool {
        matches!(self, Self::Replay(_))
    }

    /// Whether a message sent now has somewhere to go (udpin: once the autopilot is heard).
    pub fn has_peer(&self) -> bool {
        match self {
            Self::Udp(udp) => udp.peer.is_some(),
            Self::Stream(_) => true,
            Self::Replay(feed) => feed.peer_known(),
        }
    }

    /// The autopilot was heard: udpin replies to it from now on.
    pub fn learn_peer(&mut self, from: Option<SocketAddr>) {
        match (self, from) {
            (Self::Udp(udp), Some(from)) => udp.set_peer(from),
            (Self::Replay(feed), _) => feed
                .peer_known
                .store(true, std::sync::atomic::Ordering::Release),
            _ => {}
        }
    }

    /// The bound local address, for UDP.
    pub fn local_addr(&self) -> Option<SocketAddr> {
        match self {
            Self::Udp(udp) => udp.socket.local_addr().ok(),
            Self::Stream(_) | Self::Replay(_) => None,
        }
    }
}

fn no_data(error: &io::Error) -> bool {
    matches!(error.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut)
}

/// MAVLink over a UDP socket, one datagram at a time.
pub struct UdpTransport {
    socket: UdpSocket,
    /// Where datagrams go: fixed for udpout, learned from the autopilot for udpin.
    peer: Option<SocketAddr>,
    /// udpin: the peer follows the autopilot's address.
    learns_peer: bool,
    buffer: Vec<u8>,
    encode_buffer: Vec<u8>,
    signing: Option<SigningData>,
}

impl UdpTransport {
    pub fn listen(address: &impl ToSocketAddrs) -> io::Result<Transport> {
        let socket = UdpSocket::bind(address)?;
        Ok(Transport::Udp(Self::new(socket, None, true)))
    }

    pub fn send_to(address: &impl ToSocketAddrs) -> io::Result<Transport> {
        let peer = address
            .to_socket_addrs()?
            .next()
            .ok_or_else(|| io::Error::new(ErrorKind::AddrNotAvailable, "no address"))?;
        let local = if peer.is_ipv4() {
            "0.0.0.0:0"
        } else {
            "[::]:0"
        };
        let socket = UdpSocket::bind(local)?;
        Ok(Transport::Udp(Self::new(socket, Some(peer), false)))
    }

    fn new(socket: UdpSocket, peer: Option<SocketAddr>, learns_peer: bool) -> Self {
        Self {
            socket,
            peer,
            learns_peer,
            buffer: vec![0; 65_536],
            encode_buffer: Vec::with_capacity(300),
            signing: None,
        }
    }

    /// Sets where replies go (udpin learns it from the autopilot's valid datagrams).
    pub fn set_peer(&mut self, peer: SocketAddr) {
        if self.learns_peer {
            self.peer = Some(peer);
        }
    }

    fn receive(&mut self, wait: Option<Duration>) -> io::Result<Option<Incoming>> {
        match wait {
            None => self.socket.set_nonblocking(true)?,
            Some(wait) => {
                self.socket.set_nonblocking(false)?;
                // A zero timeout means "block forever" to the OS.
                self.socket
                    .set_read_timeout(Some(wait.max(Duration::from_micros(1))))?;
            }
        }
        let (length, from) = match self.socket.recv_from(&mut self.buffer) {
            Ok(received) => received,
            Err(error) if no_data(&error) => return Ok(None),
            // Linux reports an earlier send's ICMP port-unreachable here; no data, not fatal.
            Err(error) if error.kind() == ErrorKind::ConnectionRefused => return Ok(None),
            Err(error) => return Err(error),
        };
        let datagram = &self.buffer[..length];
        let messages = decode_datagram(datagram);
        let Some(signing) = &self.signing else {
            return Ok(Some(Incoming {
                malformed: messages.is_empty(),
                messages,
                from: Some(from),
                ..Incoming::default()
            }));
        };
        // Valid frames whose signature does not check out are counted apart from garbage.
        let signed = decode_datagram_signed(datagram, signing);
        Ok(Some(Incoming {
            malformed: messages.is_empty(),
            unsigned: messages.len().saturating_sub(signed.len()),
            messages: signed,
            from: Some(from),
            received_s: None,
        }))
    }

    fn send(&mut self, header: MavHeader, message: &MavMessage) -> io::Result<bool> {
        let Some(peer) = self.peer else {
            return Ok(false);
        };
        self.encode_buffer.clear();
        mavlink::write_versioned_msg_signed(
            &mut self.encode_buffer,
            MavlinkVersion::V2,
            header,
            message,
            self.signing.as_ref(),
        )
        .map_err(io::Error::other)?;
        match self.socket.send_to(&self.encode_buffer, peer) {
            Ok(_) => Ok(true),
            // Nobody listening (yet): UDP drops it, as a radio would.
            Err(error) if error.kind() == ErrorKind::ConnectionRefused => Ok(false),
            Err(error) => Err(error),
        }
    }
}

/// Every CRC-valid MAVLink 1 or 2 message in one datagram; garbage between frames is skipped.
pub fn decode_datagram(datagram: &[u8]) -> Vec<(MavHeader, MavMessage)> {
    decode_with(datagram, None)
}

/// The messages of a datagram whose MAVLink 2 signature checks out with `signing`.
pub fn decode_datagram_signed(
    datagram: &[u8],
    signing: &SigningData,
) -> Vec<(MavHeader, MavMessage)> {
    decode_with(datagram, Some(signing))
}

fn decode_with(datagram: &[u8], signing: Option<&SigningData>) -> Vec<(MavHeader, MavMessage)> {
    let mut reader = mavlink::MavlinkReader::new(datagram);
    let mut messages = Vec::new();
    // Every frame is at least 8 bytes, so this bounds the loop even if the reader misbehaves.
    for _ in 0..=datagram.len() / 8 {
        match reader.read_any_message_signed::<MavMessage>(signing) {
            Ok(message) => messages.push(message),
            // An unknown id or a bad enum value: that frame is skipped, the rest still read.
            Err(MessageReadError::Parse(_)) => {}
            Err(MessageReadError::Io(_)) => break,
        }
    }
    messages
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reason after the echoed input.
    fn why(input: &str) -> String {
        match ConnectionSpec::parse(input) {
            Err(LinkError::BadConnectionString { input: echoed, why }) => {
                assert_eq!(echoed, input);
                why
            }
            Err(error @ LinkError::NotANumber { .. }) => {
                let prefix = format!("bad MAVLink connection string {input:?}: ");
                let message = error.to_string();
                message
                    .strip_prefix(&prefix)
                    .unwrap_or_else(|| panic!("{message:?} does not echo {input:?}"))
                    .to_string()
            }
            other => panic!("{input:?} parsed: {other:?}"),
        }
    }

    /// `the port "abc" is not a number (<the parser's reason>); expected 0..=65535`, checked
    /// without spelling out the standard library's wording.
    fn assert_not_a_number(why: &str, field_and_text: &str, expected: &str) {
        assert!(
            why.starts_with(&format!("the {field_and_text} is not a number (")),
            "{why}"
        );
        assert!(why.ends_with(&format!("); expected {expected}")), "{why}");
    }

    #[test]
    fn parses_good_connection_strings() {
        assert_eq!(
            ConnectionSpec::parse("udpin:0.0.0.0:14540").unwrap(),
            ConnectionSpec::UdpIn {
                host: "0.0.0.0".into(),
                port: 14540
            }
        );
        assert_eq!(
            ConnectionSpec::parse("udpin:127.0.0.1:0").unwrap(),
            ConnectionSpec::UdpIn {
                host: "127.0.0.1".into(),
                port: 0
            }
        );
        assert_eq!(
            ConnectionSpec::parse("udpout:192.168.1.10:14557").unwrap(),
            ConnectionSpec::UdpOut {
                host: "192.168.1.10".into(),
                port: 14557
            }
        );
        assert_eq!(
            ConnectionSpec::parse("tcpout:localhost:5760").unwrap(),
            ConnectionSpec::TcpOut {
                host: "localhost".into(),
                port: 5760
            }
        );
        assert_eq!(
            ConnectionSpec::parse("serial:/dev/ttyACM0:921600").unwrap(),
            ConnectionSpec::Serial {
                device: "/dev/ttyACM0".into(),
                baud: 921_600
            }
        );
        assert_eq!(
            ConnectionSpec::parse("udpin:[::1]:14540").unwrap(),
            ConnectionSpec::UdpIn {
                host: "[::1]".into(),
                port: 14540
            }
        );
        let spec: ConnectionSpec = "serial:/dev/ttyTHS1:57600".parse().unwrap();
        assert_eq!(spec.to_string(), "serial:/dev/ttyTHS1:57600");
    }

    #[test]
    fn rejects_bad_connection_strings_with_the_reason() {
        assert_eq!(
            why(""),
            format!(
                "expected SCHEME:ADDRESS with SCHEME one of {SCHEMES} \
                 (e.g. udpin:0.0.0.0:14540 or serial:/dev/ttyACM0:921600)"
            )
        );
        assert!(why("14540").starts_with("expected SCHEME:ADDRESS"));
        assert_eq!(
            why("udp:0.0.0.0:14540"),
            "unknown scheme \"udp\"; expected one of udpin, udpout, tcpout, serial \
             (did you mean udpin, to listen, or udpout, to send?)"
        );
        assert!(why("tcpin:0.0.0.0:5760").contains("did you mean tcpout"));
        assert!(why("http://x:1").starts_with("unknown scheme \"http\""));
        assert_eq!(
            why("udpin:14540"),
            "expected udpin:HOST:PORT, found no port"
        );
        assert!(why("udpin::14540").contains("the host is empty"));
        assert_not_a_number(&why("udpin:0.0.0.0:abc"), "port \"abc\"", "0..=65535");
        assert_eq!(
            why("udpin:0.0.0.0:70000"),
            "the port 70000 is out of range; expected 0..=65535"
        );
        assert_eq!(
            why("udpout:127.0.0.1:0"),
            "the port 0 is out of range; expected 1..=65535"
        );
        assert_not_a_number(&why("tcpout:127.0.0.1:-1"), "port \"-1\"", "1..=65535");
        assert!(why("udpout:127.0.0.1:").contains("is not a number"));
        assert!(why("udpout:my host:14540").contains("whitespace"));
        assert!(why("serial:/dev/ttyACM0").contains("found no baud rate"));
        assert!(why("serial::57600").contains("the device is empty"));
        assert_not_a_number(
            &why("serial:/dev/ttyACM0:fast"),
            "baud rate \"fast\"",
            &format!("one of {BAUD_RATES:?}"),
        );
        // The parser's error is kept: a port too large for any integer says so.
        let error = ConnectionSpec::parse("udpin:0.0.0.0:99999999999").unwrap_err();
        let cause = std::error::Error::source(&error)
            .and_then(|cause| cause.downcast_ref::<std::num::ParseIntError>())
            .expect("the integer parser's error");
        assert_eq!(cause.kind(), &std::num::IntErrorKind::PosOverflow);
        assert!(error.to_string().contains(&cause.to_string()), "{error}");
        assert_eq!(
            why("serial:/dev/ttyACM0:12345"),
            format!("the baud rate 12345 is not a standard rate; expected one of {BAUD_RATES:?}")
        );
        let message = ConnectionSpec::parse("udp:1.2.3.4:5")
            .unwrap_err()
            .to_string();
        assert!(message.contains("udp:1.2.3.4:5"), "{message}");
    }

    #[test]
    fn opens_udp_on_an_os_chosen_port() {
        let transport = ConnectionSpec::parse("udpin:127.0.0.1:0")
            .unwrap()
            .open(None)
            .unwrap();
        assert_ne!(transport.local_addr().unwrap().port(), 0);
    }

    #[test]
    fn a_garbage_datagram_decodes_to_nothing() {
        assert!(decode_datagram(&[0xfd, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10]).is_empty());
        assert!(decode_datagram(&[]).is_empty());
        assert!(decode_datagram(&[0xfd; 300]).is_empty());
    }
}
