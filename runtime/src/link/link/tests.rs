use super::*;
use mavlink::dialects::common::{MavAutopilot, MavModeFlag, MavState, MavType, HEARTBEAT_DATA};
use mavlink::MavlinkVersion;
use std::net::UdpSocket;

/// A hand-rolled autopilot: raw MAVLink 2 datagrams from a plain socket.
struct RawAutopilot {
    socket: UdpSocket,
    to: SocketAddr,
    system_id: u32,
}

impl RawAutopilot {
    fn new(to: SocketAddr, system_id: u32) -> Self {
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        socket
            .set_read_timeout(Some(Duration::from_secs(1)))
            .unwrap();
        Self {
            socket,
            to,
            system_id,
        }
    }

    fn send(&self, message: &MavMessage) {
        let mut bytes = Vec::new();
        let header = MavHeader {
            system_id: self.system_id,
            component_id: 1,
            sequence: 0,
        };
        mavlink::write_versioned_msg(&mut bytes, MavlinkVersion::V2, header, message).unwrap();
        self.socket.send_to(&bytes, self.to).unwrap();
    }

    fn receive(&self) -> Vec<MavMessage> {
        let mut buffer = [0u8; 2048];
        let (length, _) = self.socket.recv_from(&mut buffer).unwrap();
        super::super::connection::decode_datagram(&buffer[..length])
            .into_iter()
            .map(|(_, message)| message)
            .collect()
    }
}

fn px4_heartbeat() -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: 6 << 16,
        mavtype: MavType::MAV_TYPE_QUADROTOR,
        autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
        base_mode: MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
        system_status: MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    })
}

fn poll_until(link: &mut MavlinkLink, now_s: f64, done: impl Fn(&MavlinkLink) -> bool) {
    let deadline = Instant::now() + Duration::from_secs(1);
    while !done(link) {
        assert!(Instant::now() < deadline, "timed out: {link:?}");
        link.poll(now_s);
        std::thread::sleep(Duration::from_millis(1));
    }
}

#[test]
fn link_answers_timesync_requests_and_sends_its_heartbeat() {
    // Not asking the autopilot's clock itself: only its own answers go out.
    let config = LinkConfig {
        timesync_period_s: 0.0,
        ..LinkConfig::default()
    };
    let mut link = MavlinkLink::bind_local_ephemeral(config).unwrap();
    assert_eq!(link.status(), LinkStatus::Connecting);
    assert_eq!(link.failsafe_action(), FailsafeAction::StopSetpoints);
    let autopilot = RawAutopilot::new(link.local_addr().unwrap(), 1);
    autopilot.send(&px4_heartbeat());
    poll_until(&mut link, 2.0, |link| {
        link.telemetry().autopilot().is_some()
    });
    // The companion's heartbeat goes to the address the autopilot spoke from.
    let MavMessage::HEARTBEAT(heartbeat) = &autopilot.receive()[0] else {
        panic!("expected the companion's HEARTBEAT first");
    };
    assert_eq!(heartbeat.mavtype, MavType::MAV_TYPE_ONBOARD_CONTROLLER);
    assert_eq!(heartbeat.autopilot, MavAutopilot::MAV_AUTOPILOT_INVALID);
    autopilot.send(&MavMessage::TIMESYNC(TIMESYNC_DATA {
        tc1: 0,
        ts1: 777,
        ..Default::default()
    }));
    poll_until(&mut link, 2.5, |link| link.stats().messages_received == 2);
    let replies = autopilot.receive();
    assert_eq!(
        replies,
        vec![MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1: 2_500_000_000,
            ts1: 777,
            target_system: 1,
            target_component: 1,
        })]
    );
}

#[test]
fn link_tracks_the_autopilots_clock_over_timesync() {
    // The autopilot's clock runs 1000.25 s ahead of the runtime's; it answers each request
    // from its own thread, as a real one does.
    const OFFSET_NS: i64 = 1_000_250_000_000;
    let mut link = MavlinkLink::bind_local_ephemeral(LinkConfig::default()).unwrap();
    let autopilot = RawAutopilot::new(link.local_addr().unwrap(), 1);
    autopilot.send(&px4_heartbeat());
    poll_until(&mut link, 0.0, |link| {
        link.telemetry().autopilot().is_some()
    });
    let answering = std::thread::spawn(move || {
        let mut answered = 0;
        while answered < 4 {
            for message in autopilot.receive() {
                if let MavMessage::TIMESYNC(request) = message {
                    assert_eq!(request.tc1, 0, "the link asks, it does not answer here");
                    assert_eq!((request.target_system, request.target_component), (1, 1));
                    autopilot.send(&MavMessage::TIMESYNC(TIMESYNC_DATA {
                        tc1: request.ts1 + OFFSET_NS,
                        ts1: request.ts1,
                        ..Default::default()
                    }));
                    answered += 1;
                }
            }
        }
    });
    // The mission loop polls every 20 ms of wall time; one request a second of runtime time.
    for k in 1..=4 {
        link.poll(k as f64);
        std::thread::sleep(Duration::from_millis(20));
    }
    answering.join().unwrap();
    let stats = link.clock_sync_stats();
    assert_eq!((stats.requests, stats.replies), (4, 4), "{stats:?}");
    // The reply was waited for: the round trip is the link's, not the loop's 20 ms.
    let round_trip_ns = stats.round_trip_ns.unwrap();
    assert!(round_trip_ns < 5_000_000, "{stats:?}");
    // The autopilot read its clock as the request left: the estimate is off by half the trip.
    let error_ns = (stats.offset_ns.unwrap() - OFFSET_NS).abs();
    assert!(error_ns <= round_trip_ns / 2 + 1, "{stats:?}");
    let there_us = link.autopilot_time_us(10.0).unwrap() as i64;
    assert!((there_us - (10_000_000 + OFFSET_NS / 1000)).abs() <= round_trip_ns / 2000 + 1);
}

#[test]
fn telemetry_from_other_systems_is_ignored() {
    let config = LinkConfig {
        target_system_id: Some(1),
        ..LinkConfig::default()
    };
    let mut link = MavlinkLink::bind_local_ephemeral(config).unwrap();
    let stranger = RawAutopilot::new(link.local_addr().unwrap(), 42);
    stranger.send(&px4_heartbeat());
    poll_until(&mut link, 0.0, |link| link.stats().ignored == 1);
    assert!(link.telemetry().autopilot().is_none());
    assert_eq!(link.status(), LinkStatus::Connecting);
    assert_eq!(link.stats().unsent_no_peer, 1);
}

#[test]
fn lockstep_without_an_autopilot_times_out_with_a_named_error() {
    let mut link = MavlinkLink::bind_local_ephemeral(LinkConfig::default()).unwrap();
    let error = link
        .poll_lockstep(20_000_000, Duration::from_millis(50))
        .unwrap_err();
    assert!(
        matches!(
            error,
            LinkError::LockstepTimeout {
                t_ns: 20_000_000,
                ..
            }
        ),
        "{error}"
    );
    assert!(error.to_string().contains("no TIMESYNC"));
}

#[test]
fn lockstep_barrier_from_the_future_is_an_error() {
    let config = LinkConfig {
        target_system_id: Some(1),
        ..LinkConfig::default()
    };
    let mut link = MavlinkLink::bind_local_ephemeral(config).unwrap();
    let autopilot = RawAutopilot::new(link.local_addr().unwrap(), 1);
    autopilot.send(&MavMessage::TIMESYNC(TIMESYNC_DATA {
        tc1: 0,
        ts1: 10,
        ..Default::default()
    }));
    autopilot.send(&MavMessage::TIMESYNC(TIMESYNC_DATA {
        tc1: 0,
        ts1: 30,
        ..Default::default()
    }));
    let error = link.poll_lockstep(20, Duration::from_secs(1)).unwrap_err();
    assert!(matches!(
        error,
        LinkError::LockstepOutOfStep {
            expected_ns: 20,
            got_ns: 30
        }
    ));
}

#[test]
fn garbage_over_udp_is_counted_not_fatal() {
    let mut link = MavlinkLink::bind_local_ephemeral(LinkConfig::default()).unwrap();
    let vandal = UdpSocket::bind("127.0.0.1:0").unwrap();
    for length in [1usize, 7, 12, 280, 1500, 65_000] {
        let datagram: Vec<u8> = (0..length).map(|i| (i * 31 % 256) as u8 | 0x01).collect();
        vandal
            .send_to(&datagram, link.local_addr().unwrap())
            .unwrap();
    }
    poll_until(&mut link, 0.0, |link| link.stats().malformed == 6);
    assert_eq!(link.stats().messages_received, 0);
}

#[test]
fn ten_thousand_random_truncated_and_mutated_datagrams_are_counted_not_fatal() {
    use rand::{Rng, SeedableRng};
    let mut link = MavlinkLink::bind_local_ephemeral(LinkConfig::default()).unwrap();
    let vandal = UdpSocket::bind("127.0.0.1:0").unwrap();
    let mut rng = rand::rngs::StdRng::seed_from_u64(16);
    let mut valid = Vec::new();
    mavlink::write_versioned_msg(
        &mut valid,
        MavlinkVersion::V2,
        MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 0,
        },
        &px4_heartbeat(),
    )
    .unwrap();
    let to = link.local_addr().unwrap();
    let mut sent = 0u64;
    let mut polled = 0u64;
    for k in 0..10_000 {
        let datagram: Vec<u8> = match k % 3 {
            // Random bytes, often starting like a MAVLink 2 frame.
            0 => {
                let length = rng.random_range(1..400);
                let mut bytes: Vec<u8> = (0..length).map(|_| rng.random()).collect();
                if rng.random_bool(0.5) {
                    bytes[0] = 0xfd;
                }
                bytes
            }
            // A valid frame cut short.
            1 => valid[..rng.random_range(1..valid.len())].to_vec(),
            // A valid frame with one byte changed after its start marker (CRC fails).
            _ => {
                let mut bytes = valid.clone();
                let at = rng.random_range(1..bytes.len());
                bytes[at] ^= rng.random_range(1..=255u8);
                bytes
            }
        };
        vandal.send_to(&datagram, to).unwrap();
        sent += 1;
        // Drain now and then so the socket buffer never overflows.
        if k % 200 == 199 {
            poll_until(&mut link, 0.0, |link| {
                link.stats().malformed + link.stats().messages_received >= sent
            });
            polled = sent;
        }
    }
    poll_until(&mut link, 0.0, |link| {
        link.stats().malformed + link.stats().messages_received >= sent
    });
    assert!(polled > 0);
    let stats = link.stats();
    // A mutated byte can land in a field the CRC covers only by chance: none get through as
    // messages except by a CRC collision, which 10,000 tries do not make likely.
    assert_eq!(stats.malformed + stats.messages_received, sent, "{stats:?}");
    assert!(stats.malformed >= sent - 2, "{stats:?}");
}

#[test]
fn with_a_signing_key_unsigned_messages_are_refused_and_what_is_sent_is_signed() {
    let key = [7u8; 32];
    let config = LinkConfig {
        signing_key: Some(key),
        ..LinkConfig::default()
    };
    let mut link = MavlinkLink::bind_local_ephemeral(config).unwrap();
    let autopilot = RawAutopilot::new(link.local_addr().unwrap(), 1);
    // Unsigned: refused, counted.
    autopilot.send(&px4_heartbeat());
    poll_until(&mut link, 0.0, |link| link.stats().unsigned == 1);
    assert!(link.telemetry().autopilot().is_none());
    // Signed with another key: refused too.
    let sign_with = |key: [u8; 32]| {
        let signing =
            mavlink::SigningData::from_config(mavlink::SigningConfig::new(key, 0, true, false));
        let mut bytes = Vec::new();
        mavlink::write_versioned_msg_signed(
            &mut bytes,
            MavlinkVersion::V2,
            MavHeader {
                system_id: 1,
                component_id: 1,
                sequence: 0,
            },
            &px4_heartbeat(),
            Some(&signing),
        )
        .unwrap();
        bytes
    };
    autopilot
        .socket
        .send_to(&sign_with([9u8; 32]), autopilot.to)
        .unwrap();
    poll_until(&mut link, 0.0, |link| link.stats().unsigned == 2);
    assert!(link.telemetry().autopilot().is_none());
    // Signed with the key: accepted.
    autopilot
        .socket
        .send_to(&sign_with(key), autopilot.to)
        .unwrap();
    poll_until(&mut link, 0.0, |link| {
        link.telemetry().autopilot().is_some()
    });
    // The companion's heartbeat back is signed with the key: it verifies with it only.
    let mut buffer = [0u8; 2048];
    let (length, _) = autopilot.socket.recv_from(&mut buffer).unwrap();
    let verify = |key: [u8; 32]| {
        let signing =
            mavlink::SigningData::from_config(mavlink::SigningConfig::new(key, 0, false, false));
        super::super::connection::decode_datagram_signed(&buffer[..length], &signing).len()
    };
    assert_eq!(verify(key), 1);
    assert_eq!(verify([9u8; 32]), 0);
}

/// A `tcpout` link to a local TCP server that accepted its connection and closed it at once
/// (an autopilot that stopped or restarted); the server stays, to take a new connection.
fn tcp_link_closed_by_its_peer() -> (std::net::TcpListener, MavlinkLink) {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let link =
        MavlinkLink::connect(&format!("tcpout:127.0.0.1:{port}"), LinkConfig::default()).unwrap();
    let (peer, _) = listener.accept().unwrap();
    drop(peer);
    (listener, link)
}

/// An autopilot whose TCP link closes (a SITL that stopped) refuses every send and receive:
/// the link counts them, tries its heartbeat (and TIMESYNC) once a period rather than on
/// every poll, and goes on polling.
#[test]
fn a_closed_tcp_link_is_counted_and_retried_at_the_heartbeat_period() {
    let (listener, mut link) = tcp_link_closed_by_its_peer();
    drop(listener);
    // Two seconds of the runner's 1 kHz polls.
    for step in 0..2000 {
        link.poll(f64::from(step) * 1e-3);
    }
    let stats = link.stats();
    assert!(stats.receive_failures > 0, "{stats:?}");
    // A heartbeat and a TIMESYNC request at 0, 1 and 2 s at most (one of the first may still
    // have gone out before the peer's reset came back).
    assert!(
        (1..=6).contains(&stats.send_failures),
        "send failures {}: retried on every poll?",
        stats.send_failures
    );
}

/// An autopilot's TCP server that closes the runtime's connection and takes a new one (a SITL
/// restarted on its port) is dialled again: a heartbeat on the new connection reaches the link,
/// and no poll waits for the dial.
#[test]
fn a_tcp_link_whose_connection_closes_dials_again() {
    let (listener, mut link) = tcp_link_closed_by_its_peer();
    listener.set_nonblocking(true).unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    let mut step = 0;
    let mut second = loop {
        assert!(Instant::now() < deadline, "not dialled again: {link:?}");
        link.poll(f64::from(step) * 1e-3);
        step += 1;
        if let Ok((stream, _)) = listener.accept() {
            break stream;
        }
        std::thread::sleep(Duration::from_millis(1));
    };
    // Once the dial's thread is done the new connection is the link's.
    let header = MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: 0,
    };
    let mut bytes = Vec::new();
    mavlink::write_versioned_msg(&mut bytes, MavlinkVersion::V2, header, &px4_heartbeat()).unwrap();
    std::io::Write::write_all(&mut second, &bytes).unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    while link.telemetry().autopilot().is_none() {
        assert!(Instant::now() < deadline, "no heartbeat: {link:?}");
        link.poll(f64::from(step) * 1e-3);
        step += 1;
        std::thread::sleep(Duration::from_millis(1));
    }
    assert_eq!(link.stats().redials, 1);
    assert!(link.stats().receive_failures > 0);
}
