use super::*;
use nalgebra::{UnitQuaternion, Vector3};

/// A servo packet written byte by byte, as ArduPilot's `output_servos` lays it out.
fn packet_bytes(magic: u16, frame_rate_hz: u16, frame_count: u32, pwm_us: &[u16]) -> Vec<u8> {
    let mut bytes = Vec::new();
    bytes.extend_from_slice(&magic.to_le_bytes());
    bytes.extend_from_slice(&frame_rate_hz.to_le_bytes());
    bytes.extend_from_slice(&frame_count.to_le_bytes());
    for pwm in pwm_us {
        bytes.extend_from_slice(&pwm.to_le_bytes());
    }
    bytes
}

fn sixteen(first: [u16; 4]) -> Vec<u16> {
    let mut pwm = vec![0u16; 16];
    pwm[..4].copy_from_slice(&first);
    pwm
}

fn state() -> BodyState {
    BodyState {
        position_ned_m: Vector3::new(1.5, -2.25, -5.0),
        velocity_ned_m_s: Vector3::new(0.1, 0.0, -0.000_013),
        acceleration_ned_m_s2: Vector3::new(0.0, 0.2, 0.0),
        attitude: UnitQuaternion::from_euler_angles(0.1, -0.2, 1.0),
        body_rates_rad_s: Vector3::new(0.01, 0.0, -0.02),
    }
}

fn imu() -> ImuSample {
    ImuSample {
        accel_frd_m_s2: Vector3::new(0.12, -0.000_001, -9.81),
        gyro_frd_rad_s: Vector3::new(1.3e-5, -2.5e-7, 0.25),
        mag_frd_gauss: Vector3::new(0.21, 0.01, 0.43),
        pressure_hpa: 955.5,
        pressure_altitude_m: 488.0,
        temperature_c: 11.8,
    }
}

#[test]
fn a_sixteen_channel_packet_parses_and_its_first_four_channels_are_the_motors() {
    let bytes = packet_bytes(18458, 1200, 7, &sixteen([1000, 1500, 2000, 2100]));
    assert_eq!(bytes.len(), 40);
    let packet = ServoPacket::parse(&bytes).unwrap();
    assert_eq!(packet.frame_rate_hz, 1200);
    assert_eq!(packet.frame_count, 7);
    assert_eq!(packet.pwm_us.len(), 16);
    assert_eq!(packet.pwm_us[1], 1500);
    // Above 2000 µs saturates; the step is 1/frame rate.
    assert_eq!(packet.motor_commands(), [0.0, 0.5, 1.0, 1.0]);
    assert!((packet.step_s() - 1.0 / 1200.0).abs() < 1e-15);
    assert_eq!(packet.to_bytes(), bytes);
}

#[test]
fn unused_or_low_channels_are_stopped_motors() {
    let packet =
        ServoPacket::parse(&packet_bytes(18458, 400, 1, &sixteen([0, 900, 1100, 1999]))).unwrap();
    let commands = packet.motor_commands();
    assert_eq!(commands[..2], [0.0, 0.0]);
    assert!((commands[2] - 0.1).abs() < 1e-12 && (commands[3] - 0.999).abs() < 1e-12);
}

#[test]
fn a_thirty_two_channel_packet_parses() {
    let pwm: Vec<u16> = (0..32).map(|k| 1000 + 10 * k).collect();
    let bytes = packet_bytes(29569, 1200, 99, &pwm);
    assert_eq!(bytes.len(), 72);
    let packet = ServoPacket::parse(&bytes).unwrap();
    assert_eq!(packet.pwm_us, pwm);
    assert_eq!(packet.to_bytes(), bytes);
    // The 32-channel magic on a 16-channel body is cut short.
    let short = packet_bytes(29569, 1200, 99, &pwm[..16]);
    assert_eq!(
        ServoPacket::parse(&short),
        Err(ServoPacketError::Length {
            bytes: 40,
            expected: 72,
            channels: 32
        })
    );
}

#[test]
fn wrong_magic_short_long_and_zero_rate_packets_are_refused_by_name() {
    let wrong = ServoPacket::parse(&packet_bytes(1234, 1200, 1, &sixteen([1000; 4]))).unwrap_err();
    assert_eq!(
        wrong,
        ServoPacketError::WrongMagic {
            found: 1234,
            bytes: 40
        }
    );
    assert!(wrong.to_string().contains("magic 1234"), "{wrong}");
    let good = packet_bytes(18458, 1200, 1, &sixteen([1000; 4]));
    let short = ServoPacket::parse(&good[..39]).unwrap_err();
    assert_eq!(
        short,
        ServoPacketError::Length {
            bytes: 39,
            expected: 40,
            channels: 16
        }
    );
    assert!(short.to_string().contains("39 bytes"), "{short}");
    let mut long = good.clone();
    long.push(0);
    assert!(matches!(
        ServoPacket::parse(&long),
        Err(ServoPacketError::Length { bytes: 41, .. })
    ));
    for tiny in [&[][..], &[0x1a][..]] {
        assert!(matches!(
            ServoPacket::parse(tiny),
            Err(ServoPacketError::Length { expected: 40, .. })
        ));
    }
    assert_eq!(
        ServoPacket::parse(&packet_bytes(18458, 0, 5, &sixteen([1000; 4]))),
        Err(ServoPacketError::ZeroFrameRate { frame_count: 5 })
    );
}

/// A JSON value, as far as the reply uses JSON.
#[derive(Debug, Clone, PartialEq)]
enum Json {
    Number(f64),
    Array(Vec<Json>),
    Object(Vec<(String, Json)>),
}

impl Json {
    fn get(&self, key: &str) -> &Json {
        match self {
            Json::Object(fields) => &fields.iter().find(|(k, _)| k == key).unwrap().1,
            other => panic!("{other:?} has no {key}"),
        }
    }

    fn numbers(&self) -> Vec<f64> {
        match self {
            Json::Number(n) => vec![*n],
            Json::Array(items) => items.iter().flat_map(Json::numbers).collect(),
            other => panic!("{other:?} is not numbers"),
        }
    }
}

/// A strict reader of the JSON subset the reply is: objects, arrays, numbers, no whitespace.
fn parse_json(text: &str) -> Json {
    fn value(s: &[u8], i: &mut usize) -> Json {
        match s[*i] {
            b'{' => {
                *i += 1;
                let mut fields = Vec::new();
                while s[*i] != b'}' {
                    if !fields.is_empty() {
                        assert_eq!(s[*i], b',', "at {i}");
                        *i += 1;
                    }
                    assert_eq!(s[*i], b'"', "at {i}");
                    let end = *i + 1 + s[*i + 1..].iter().position(|&c| c == b'"').unwrap();
                    let key = String::from_utf8(s[*i + 1..end].to_vec()).unwrap();
                    assert_eq!(s[end + 1], b':', "after {key}");
                    *i = end + 2;
                    fields.push((key, value(s, i)));
                }
                *i += 1;
                Json::Object(fields)
            }
            b'[' => {
                *i += 1;
                let mut items = Vec::new();
                while s[*i] != b']' {
                    if !items.is_empty() {
                        assert_eq!(s[*i], b',', "at {i}");
                        *i += 1;
                    }
                    items.push(value(s, i));
                }
                *i += 1;
                Json::Array(items)
            }
            _ => {
                let start = *i;
                while *i < s.len() && matches!(s[*i], b'-' | b'.' | b'0'..=b'9') {
                    *i += 1;
                }
                let text = std::str::from_utf8(&s[start..*i]).unwrap();
                // Digits, one point, a sign: fixed point, no exponent.
                assert!(text.matches('.').count() == 1, "{text}");
                Json::Number(text.parse().unwrap_or_else(|_| panic!("{text}")))
            }
        }
    }
    let bytes = text.as_bytes();
    let mut i = 0;
    let parsed = value(bytes, &mut i);
    assert_eq!(i, bytes.len(), "trailing text in {text}");
    parsed
}

#[test]
fn the_reply_is_one_fixed_point_json_line_that_reads_back_to_the_state() {
    let (s, m) = (state(), imu());
    let line = state_json(12.345, &s, &m, Some(4.98)).unwrap();
    // Framed by newlines, one line, no spaces: ArduPilot's reader wants `"key":value`.
    assert!(line.starts_with("\n{") && line.ends_with("}\n"), "{line:?}");
    let body = &line[1..line.len() - 1];
    assert!(!body.contains('\n') && !body.contains(' '), "{line:?}");
    // The tiny gyro value is written in full, never as 1.3e-05.
    assert!(
        body.contains("\"gyro\":[0.000013,-0.000000,0.250000]"),
        "{body}"
    );
    assert!(!body.contains("e-") && !body.contains("e+"), "{body}");
    let json = parse_json(body);
    let close = |a: &[f64], b: &[f64], tolerance: f64| {
        assert_eq!(a.len(), b.len());
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= tolerance, "{a:?} vs {b:?}");
        }
    };
    close(&json.get("timestamp").numbers(), &[12.345], 1e-9);
    let imu_json = json.get("imu");
    close(
        &imu_json.get("gyro").numbers(),
        m.gyro_frd_rad_s.as_slice(),
        5e-7,
    );
    close(
        &imu_json.get("accel_body").numbers(),
        m.accel_frd_m_s2.as_slice(),
        5e-7,
    );
    close(
        &json.get("position").numbers(),
        s.position_ned_m.as_slice(),
        5e-7,
    );
    close(
        &json.get("velocity").numbers(),
        s.velocity_ned_m_s.as_slice(),
        5e-7,
    );
    close(&json.get("rng_1").numbers(), &[4.98], 5e-7);
    // The quaternion is w, x, y, z of the FRD → NED rotation: it turns the body's nose (FRD x)
    // to the yaw of 1 rad.
    let q = json.get("quaternion").numbers();
    let read = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
    assert!(read.angle_to(&s.attitude) < 1e-8);
    let (roll, pitch, yaw) = read.euler_angles();
    close(&[roll, pitch, yaw], &[0.1, -0.2, 1.0], 1e-8);
}

#[test]
fn large_values_stay_fixed_point_and_no_return_is_beyond_any_range() {
    let mut s = state();
    s.position_ned_m = Vector3::new(1.0e9, -123_456.5, 2.5e-9);
    let line = state_json(1.0e7, &s, &imu(), None).unwrap();
    let json = parse_json(line.trim());
    assert_eq!(json.get("timestamp").numbers(), [1.0e7]);
    assert_eq!(json.get("position").numbers(), [1.0e9, -123_456.5, 0.0]);
    assert_eq!(json.get("rng_1").numbers(), [NO_RETURN_RANGE_M]);
}

#[test]
fn a_non_finite_state_is_an_error_naming_the_field() {
    let mut m = imu();
    m.accel_frd_m_s2.y = f64::NAN;
    let error = state_json(1.0, &state(), &m, Some(2.0)).unwrap_err();
    assert!(
        matches!(
            error,
            JsonBackendError::NonFinite {
                field: "imu.accel_body",
                ..
            }
        ),
        "{error}"
    );
    let error = state_json(f64::INFINITY, &state(), &imu(), None).unwrap_err();
    assert!(error.to_string().contains("timestamp"), "{error}");
    let error = state_json(1.0, &state(), &imu(), Some(f64::NAN)).unwrap_err();
    assert!(error.to_string().contains("rng_1"), "{error}");
}

/// A socket standing in for ArduPilot: it sends from its own port, as arducopter does.
fn fake_ardupilot() -> UdpSocket {
    let socket = UdpSocket::bind(("127.0.0.1", 0)).unwrap();
    socket
        .set_read_timeout(Some(Duration::from_secs(2)))
        .unwrap();
    socket
}

fn read_line(socket: &UdpSocket) -> String {
    let mut buffer = [0u8; 2048];
    let (n, _) = socket.recv_from(&mut buffer).unwrap();
    String::from_utf8(buffer[..n].to_vec()).unwrap()
}

#[test]
fn servo_packets_over_udp_are_answered_at_their_source_and_resends_get_the_same_answer() {
    let mut backend = ArduPilotJson::bind(201).unwrap();
    assert_eq!(backend.port(), 9002 + 2010);
    let ardupilot = fake_ardupilot();
    let to = ("127.0.0.1", backend.port());
    ardupilot
        .send_to(&packet_bytes(18458, 1200, 0, &sixteen([1100; 4])), to)
        .unwrap();
    let packet = backend.receive_servos(Duration::from_secs(2)).unwrap();
    assert_eq!(packet.frame_count, 0);
    assert!(!backend.is_resend(&packet));
    assert_eq!(backend.peer(), Some(ardupilot.local_addr().unwrap()));
    backend
        .send_state(packet.step_s(), &state(), &imu(), Some(5.0))
        .unwrap();
    let first = read_line(&ardupilot);
    assert_eq!(
        first,
        state_json(packet.step_s(), &state(), &imu(), Some(5.0)).unwrap()
    );

    // The same frame again: a resend, answered with the same bytes.
    ardupilot
        .send_to(&packet_bytes(18458, 1200, 0, &sixteen([1100; 4])), to)
        .unwrap();
    let again = backend.receive_servos(Duration::from_secs(2)).unwrap();
    assert!(backend.is_resend(&again));
    assert!(backend.resend_last_state().unwrap());
    assert_eq!(read_line(&ardupilot), first);

    // Garbage between frames is skipped and counted; the next frame is new.
    ardupilot.send_to(b"hello", to).unwrap();
    ardupilot
        .send_to(&packet_bytes(18458, 1200, 1, &sixteen([1500; 4])), to)
        .unwrap();
    let next = backend.receive_servos(Duration::from_secs(2)).unwrap();
    assert_eq!(next.frame_count, 1);
    assert!(!backend.is_resend(&next));
    assert_eq!(next.motor_commands(), [0.5; 4]);
    assert_eq!(backend.bad_packets(), 1);
}

#[test]
fn only_garbage_or_nothing_is_a_named_silent_error_within_the_timeout() {
    let mut backend = ArduPilotJson::bind(202).unwrap();
    let ardupilot = fake_ardupilot();
    let to = ("127.0.0.1", backend.port());
    ardupilot
        .send_to(&packet_bytes(1234, 1200, 0, &sixteen([1000; 4])), to)
        .unwrap();
    ardupilot.send_to(&[0x1a, 0x48, 0x01], to).unwrap();
    let start = Instant::now();
    let error = backend
        .receive_servos(Duration::from_millis(300))
        .unwrap_err();
    let waited = start.elapsed();
    assert!(
        waited >= Duration::from_millis(300) && waited < Duration::from_secs(2),
        "{waited:?}"
    );
    match &error {
        JsonBackendError::Silent {
            port,
            bad_packets,
            last_bad,
            ..
        } => {
            assert_eq!(*port, 9002 + 2020);
            assert_eq!(*bad_packets, 2);
            assert!(matches!(
                last_bad,
                Some(ServoPacketError::Length { bytes: 3, .. })
            ));
        }
        other => panic!("{other}"),
    }
    let text = error.to_string();
    assert!(
        text.contains("11022") && text.contains("2 bad datagrams") && text.contains("3 bytes"),
        "{text}"
    );

    // Nothing at all.
    let start = Instant::now();
    let error = backend
        .receive_servos(Duration::from_millis(200))
        .unwrap_err();
    assert!(start.elapsed() < Duration::from_secs(2));
    assert!(
        matches!(
            error,
            JsonBackendError::Silent {
                bad_packets: 0,
                last_bad: None,
                ..
            }
        ),
        "{error}"
    );
    assert_eq!(backend.bad_packets(), 2);
}

#[test]
fn answering_before_any_packet_or_binding_a_taken_port_are_errors() {
    let mut backend = ArduPilotJson::bind(203).unwrap();
    assert!(matches!(
        backend.send_state(0.1, &state(), &imu(), None),
        Err(JsonBackendError::NoPeer)
    ));
    assert!(!backend.resend_last_state().unwrap());
    let taken = ArduPilotJson::bind(203).unwrap_err();
    assert!(
        matches!(
            taken,
            JsonBackendError::Bind {
                port: 11032,
                instance: 203,
                ..
            }
        ),
        "{taken}"
    );
    assert!(taken.to_string().contains("11032"), "{taken}");
}

/// A quiet world: the tractor parked far away, no wind; the body on the ground at the origin.
fn quiet_world_and_vehicle(instance: u8) -> (sim::world::World, ArduPilotVehicle) {
    use sim::quadrotor::QuadrotorParams;
    use sim::sensors::{Home, SensorParams};
    use sim::tractor::{PathKind, Tractor, TractorParams};
    use sim::wind::{Wind, WindConfig};
    let tractor = Tractor::new(
        PathKind::Straight,
        TractorParams::default(),
        [1_000.0, 1_000.0],
        0.0,
    )
    .unwrap()
    .parked();
    let world = World::new(tractor, Wind::new(WindConfig::Calm, 1).unwrap());
    let body = Quadrotor::on_ground(QuadrotorParams::default(), Vector3::zeros()).unwrap();
    let sensors = Sensors::new(SensorParams::default(), Home::default(), 1);
    let vehicle = ArduPilotVehicle::new(ArduPilotJson::bind(instance).unwrap(), body, sensors);
    (world, vehicle)
}

fn timestamp_of(line: &str) -> f64 {
    parse_json(line.trim()).get("timestamp").numbers()[0]
}

#[test]
fn the_vehicle_steps_the_world_once_per_new_frame_and_answers_a_resend_without_stepping() {
    let (mut world, mut vehicle) = quiet_world_and_vehicle(204);
    assert_eq!(vehicle.step_timeout, Duration::from_secs(5));
    assert_eq!(vehicle.time_s, 0.0);
    assert!(!vehicle.motors_spinning());
    let ardupilot = fake_ardupilot();
    let to = ("127.0.0.1", vehicle.json.port());

    // Frame 0 at 400 Hz, motors still (disarmed): one step of 1/400 s, answered at its end.
    let frame_0 = packet_bytes(18458, 400, 0, &sixteen([1000; 4]));
    ardupilot.send_to(&frame_0, to).unwrap();
    vehicle.step(&mut world).unwrap();
    assert!(
        (vehicle.time_s - 1.0 / 400.0).abs() < 1e-15,
        "{}",
        vehicle.time_s
    );
    assert_eq!((vehicle.frames, vehicle.resends), (1, 0));
    assert!(!vehicle.motors_spinning());
    let first = read_line(&ardupilot);
    assert!((timestamp_of(&first) - 1.0 / 400.0).abs() < 1e-9, "{first}");
    // On the ground with the motors still, the IMU's specific force points up (FRD −z).
    let accel = parse_json(first.trim())
        .get("imu")
        .get("accel_body")
        .numbers();
    assert!((accel[2] + 9.8).abs() < 0.5, "{accel:?}");

    // Frame 0 again: the same bytes back, the world not stepped.
    ardupilot.send_to(&frame_0, to).unwrap();
    vehicle.step(&mut world).unwrap();
    assert!(
        (vehicle.time_s - 1.0 / 400.0).abs() < 1e-15,
        "{}",
        vehicle.time_s
    );
    assert_eq!((vehicle.frames, vehicle.resends), (1, 1));
    assert_eq!(read_line(&ardupilot), first);

    // Frame 1, one motor at ArduPilot's spin-when-armed: the next 1/400 s.
    ardupilot
        .send_to(
            &packet_bytes(18458, 400, 1, &sixteen([1000, 1000, 1100, 1000])),
            to,
        )
        .unwrap();
    vehicle.step(&mut world).unwrap();
    assert!(
        (vehicle.time_s - 2.0 / 400.0).abs() < 1e-15,
        "{}",
        vehicle.time_s
    );
    assert_eq!((vehicle.frames, vehicle.resends), (2, 1));
    assert!(vehicle.motors_spinning());
    assert!((timestamp_of(&read_line(&ardupilot)) - 2.0 / 400.0).abs() < 1e-9);

    // A new frame rate is a new step: frame 2 at 1200 Hz advances 1/1200 s.
    ardupilot
        .send_to(&packet_bytes(18458, 1200, 2, &sixteen([1000; 4])), to)
        .unwrap();
    vehicle.step(&mut world).unwrap();
    let expected_s = 2.0 / 400.0 + 1.0 / 1200.0;
    assert!(
        (vehicle.time_s - expected_s).abs() < 1e-15,
        "{}",
        vehicle.time_s
    );
    assert!((timestamp_of(&read_line(&ardupilot)) - expected_s).abs() < 1e-9);
    assert!(!vehicle.motors_spinning());

    // Silence: the named error within the timeout, the world where it was.
    vehicle.step_timeout = Duration::from_millis(250);
    let start = Instant::now();
    let error = vehicle.step(&mut world).unwrap_err();
    let waited = start.elapsed();
    assert!(
        waited >= Duration::from_millis(250) && waited < Duration::from_secs(2),
        "{waited:?}"
    );
    assert!(
        matches!(
            error,
            JsonBackendError::Silent {
                port: 11042,
                instance: 204,
                bad_packets: 0,
                ..
            }
        ),
        "{error}"
    );
    assert!((vehicle.time_s - expected_s).abs() < 1e-15);
    assert_eq!((vehicle.frames, vehicle.resends), (3, 1));
}

#[test]
fn the_start_arguments_carry_the_world_s_home_and_each_parameter_once() {
    let args = world_start_args();
    // PX4 SITL's default home (PX4_HOME_LAT/LON/ALT), where the world's sensors are.
    assert!(args.ends_with(" -O 47.397742,8.545594,488,0"), "{args}");
    assert!(args.starts_with("-M JSON:127.0.0.1 -s 100 "), "{args}");
    let words: Vec<&str> = args.split_whitespace().collect();
    let settings: Vec<&str> = words
        .windows(2)
        .filter(|pair| pair[0] == "-P")
        .map(|pair| pair[1])
        .collect();
    let all: Vec<&(&str, &str)> = WORLD_PARAMETERS
        .iter()
        .chain(VISION_LANDING_PARAMETERS)
        .collect();
    assert_eq!(settings.len(), all.len(), "{args}");
    for (name, value) in all {
        let setting = format!("{name}={value}");
        assert_eq!(
            settings.iter().filter(|s| **s == setting).count(),
            1,
            "{setting} in {args}"
        );
    }
}
