use super::*;
use nalgebra::Vector3;
use std::io::Read;

fn sample() -> ImuSample {
    ImuSample {
        accel_frd_m_s2: Vector3::new(0.1, -0.2, -9.8),
        gyro_frd_rad_s: Vector3::new(0.01, 0.02, -0.03),
        mag_frd_gauss: Vector3::new(0.21, 0.01, 0.43),
        pressure_hpa: 955.5,
        pressure_altitude_m: 488.0,
        temperature_c: 11.8,
    }
}

/// A stand-in for PX4's `simulator_mavlink`: connects, reads what the world sends, and
/// answers as `answer` says.
fn fake_px4(
    port: u16,
    answer: impl FnOnce(TcpStream) + Send + 'static,
) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let stream = TcpStream::connect(("127.0.0.1", port)).unwrap();
        answer(stream);
    })
}

fn actuator_bytes(time_usec: u64, motors: [f32; 4], armed: bool) -> Vec<u8> {
    let mut controls = [0.0f32; 16];
    controls[..4].copy_from_slice(&motors);
    let message =
        MavMessage::HIL_ACTUATOR_CONTROLS(mavlink::dialects::common::HIL_ACTUATOR_CONTROLS_DATA {
            time_usec,
            controls,
            mode: if armed {
                MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED
            } else {
                MavModeFlag::empty()
            },
            ..Default::default()
        });
    let mut bytes = Vec::new();
    mavlink::write_versioned_msg(
        &mut bytes,
        MavlinkVersion::V2,
        MavHeader::default(),
        &message,
    )
    .unwrap();
    bytes
}

#[test]
fn sensors_go_out_as_hil_messages_and_motor_commands_come_back() {
    let instance = 207;
    let listener = Px4Hil::listen(instance).unwrap();
    let port = PX4_SIMULATOR_PORT + 207;
    let peer = fake_px4(port, |stream| {
        let mut reader = MavlinkReader::new(stream.try_clone().unwrap());
        let mut seen = Vec::new();
        // Heartbeat, sensors, GPS, distance: then answer.
        while seen.len() < 4 {
            let (_, message) = reader.read_any_message::<MavMessage>().unwrap();
            seen.push(message);
        }
        let sensor = seen
            .iter()
            .find_map(|m| match m {
                MavMessage::HIL_SENSOR(s) => Some(s.clone()),
                _ => None,
            })
            .expect("HIL_SENSOR");
        assert_eq!(sensor.time_usec, 1_500_000);
        assert!((sensor.zacc + 9.8).abs() < 1e-6);
        assert!((sensor.abs_pressure - 955.5).abs() < 1e-3);
        assert_eq!(sensor.fields_updated.bits(), 0x1FFF);
        let gps = seen
            .iter()
            .find_map(|m| match m {
                MavMessage::HIL_GPS(g) => Some(g.clone()),
                _ => None,
            })
            .expect("HIL_GPS");
        assert_eq!(
            (gps.lat, gps.lon, gps.alt),
            (473_977_420, 85_455_940, 488_000)
        );
        // 1 m/s north, 1 m/s east: 141 cm/s at 45°.
        assert_eq!((gps.vel, gps.cog, gps.vn, gps.ve), (141, 4500, 100, 100));
        assert!(seen
            .iter()
            .any(|m| matches!(m, MavMessage::DISTANCE_SENSOR(d) if d.current_distance == 250)));
        // Garbage first: it is skipped.
        let mut stream = stream;
        stream.write_all(b"\xfd\x01garbage bytes").unwrap();
        stream
            .write_all(&actuator_bytes(
                1_500_000,
                [0.6, 0.61, 0.62, f32::NAN],
                true,
            ))
            .unwrap();
        std::thread::sleep(Duration::from_millis(100));
    });
    let mut hil = Px4Hil::accept(&listener, instance, Duration::from_secs(5)).unwrap();
    let fix = GpsFix {
        latitude_deg: 47.397742,
        longitude_deg: 8.545594,
        altitude_m: 488.0,
        velocity_ned_m_s: Vector3::new(1.0, 1.0, 0.0),
        horizontal_accuracy_m: 0.4,
        vertical_accuracy_m: 0.8,
        satellites: 12,
    };
    hil.send_sensors(0.5, &sample(), Some(&fix), Some(Some(2.5)))
        .unwrap();
    let commands = hil.receive_motors(0.5).unwrap();
    assert!(commands.armed);
    assert_eq!(commands.time_usec, 1_500_000);
    assert!((commands.motors[2] - 0.62).abs() < 1e-6);
    assert!(commands.motors[3].is_nan());
    peer.join().unwrap();
}

#[test]
fn no_px4_is_a_named_error_within_the_timeout() {
    let listener = Px4Hil::listen(208).unwrap();
    let start = Instant::now();
    let Err(error) = Px4Hil::accept(&listener, 208, Duration::from_millis(300)) else {
        panic!("nobody connects, yet it accepted");
    };
    assert!(
        matches!(error, Px4HilError::NoConnection { port: 4768, .. }),
        "{error}"
    );
    assert!(start.elapsed() < Duration::from_secs(2));
}

#[test]
fn a_silent_or_babbling_peer_is_a_stall_within_the_timeout() {
    let instance = 209;
    let listener = Px4Hil::listen(instance).unwrap();
    let peer = fake_px4(PX4_SIMULATOR_PORT + 209, |mut stream| {
        // Reads the sensors, answers with garbage only, then holds the connection open.
        let mut buffer = [0u8; 256];
        let _ = stream.read(&mut buffer);
        stream.write_all(&[0x55; 300]).unwrap();
        std::thread::sleep(Duration::from_millis(800));
    });
    let mut hil = Px4Hil::accept(&listener, instance, Duration::from_secs(5)).unwrap();
    hil.step_timeout = Duration::from_millis(400);
    hil.send_sensors(0.0, &sample(), None, None).unwrap();
    let start = Instant::now();
    let Err(error) = hil.receive_motors(0.0) else {
        panic!("garbage gave motor commands");
    };
    assert!(
        matches!(error, Px4HilError::Stalled { bytes: 300, .. }),
        "{error}"
    );
    assert!(start.elapsed() < Duration::from_secs(1));
    peer.join().unwrap();
    // The peer gone: a named error, not a hang.
    let Err(error) = hil.receive_motors(0.004) else {
        panic!("a closed peer gave motor commands");
    };
    assert!(
        matches!(error, Px4HilError::Closed | Px4HilError::Stalled { .. }),
        "{error}"
    );
}
