use super::*;
use crate::tractor::PadState;

const G: f64 = 9.80665;

/// A pad far away, so only the ground is under the body.
fn far_pad() -> PadState {
    PadState {
        centre_ned_m: Vector3::new(1_000.0, 1_000.0, -1.5),
        yaw_rad: 0.0,
        velocity_ned_m_s: Vector3::zeros(),
        half_size_m: 0.75,
    }
}

fn still_air() -> QuadrotorParams {
    QuadrotorParams {
        drag: crate::vehicle::Drag {
            linear_horizontal_n_s_per_m: 0.0,
            quadratic_horizontal_n_s2_per_m2: 0.0,
            linear_vertical_n_s_per_m: 0.0,
            quadratic_vertical_n_s2_per_m2: 0.0,
        },
        rotational_damping_n_m_s: 0.0,
        ..QuadrotorParams::default()
    }
}

fn fly(body: &mut Quadrotor, seconds: f64, commands: [f64; 4], pad: &PadState) {
    let dt = 0.004;
    let steps = (seconds / dt).round() as usize;
    for i in 0..steps {
        let t = (i + 1) as f64 * dt;
        body.set_motor_commands(commands);
        body.step(dt, t, Vector3::zeros(), pad).unwrap();
    }
}

#[test]
fn the_iris_hovers_at_the_command_its_thrust_curve_gives() {
    let p = QuadrotorParams::default();
    // Independent: 1.52 kg × g over four rotors of 8.54858e-6 · 1100² N, thrust ∝ command².
    let per_rotor_max = 8.54858e-6_f64 * 1_210_000.0;
    let expected = (1.52 * G / 4.0 / per_rotor_max).sqrt();
    assert!((p.hover_command() - expected).abs() < 1e-12);
    assert!(
        (0.55..0.65).contains(&expected),
        "hover at {expected} of full command"
    );
    let mut body = Quadrotor::airborne(p, Vector3::new(0.0, 0.0, -10.0), Vector3::zeros()).unwrap();
    fly(&mut body, 2.0, [p.hover_command(); 4], &far_pad());
    let s = body.state();
    assert!(s.velocity_ned_m_s.norm() < 1e-6, "{}", s.velocity_ned_m_s);
    assert!((s.position_ned_m.z + 10.0).abs() < 1e-6);
    // The accelerometer feels the thrust: −g along body z.
    let f = s.specific_force_frd_m_s2();
    assert!((f - Vector3::new(0.0, 0.0, -G)).norm() < 1e-6, "{f}");
}

#[test]
fn without_thrust_it_falls_as_a_stone_and_the_accelerometer_reads_zero() {
    let mut body =
        Quadrotor::airborne(still_air(), Vector3::new(0.0, 0.0, -50.0), Vector3::zeros()).unwrap();
    // Spin the rotors down first (25 ms time constant), then time the fall.
    fly(&mut body, 0.4, [0.0; 4], &far_pad());
    let v0 = body.velocity_ned_m_s().z;
    let z0 = body.position_ned_m().z;
    fly(&mut body, 1.0, [0.0; 4], &far_pad());
    // The rotors still turn at e^(−1.4/0.025) of hover: nothing.
    let expected_z = z0 + v0 * 1.0 + 0.5 * G;
    assert!(
        (body.position_ned_m().z - expected_z).abs() < 0.01,
        "{} vs {expected_z}",
        body.position_ned_m().z
    );
    assert!(body.state().specific_force_frd_m_s2().norm() < 1e-3);
}

#[test]
fn each_rotor_turns_the_body_the_way_px4s_geometry_says() {
    let p = still_air();
    let hover = p.hover_command();
    let start = || Quadrotor::airborne(p, Vector3::new(0.0, 0.0, -20.0), Vector3::zeros()).unwrap();
    let rates_after = |commands: [f64; 4]| {
        let mut body = start();
        fly(&mut body, 0.2, commands, &far_pad());
        body.state().body_rates_rad_s
    };
    // Rotor 0 sits front right: more of it rolls left and pitches up.
    let r = rates_after([hover + 0.05, hover, hover, hover]);
    assert!(r.x < -0.05 && r.y > 0.05, "{r}");
    // Rotors 0 and 1 (KM > 0, counter-clockwise) faster: the body yaws clockwise (+z FRD);
    // the other pair: anticlockwise. (The Iris's front arms are longer than its rear ones, so
    // a yaw command rolls it too: PX4's allocation knows.)
    let r = rates_after([hover + 0.05, hover + 0.05, hover - 0.05, hover - 0.05]);
    assert!(r.z > 0.05, "{r}");
    let r = rates_after([hover - 0.05, hover - 0.05, hover + 0.05, hover + 0.05]);
    assert!(r.z < -0.05, "{r}");
    // Both front rotors faster: pure pitch up, no roll.
    let r = rates_after([hover + 0.05, hover, hover + 0.05, hover]);
    assert!(r.y > 0.05 && r.x.abs() < 0.05 * r.y, "{r}");
}

#[test]
fn a_steady_torque_accelerates_the_rates_as_torque_over_inertia() {
    let p = still_air();
    let hover = p.hover_command();
    let mut body = Quadrotor::airborne(p, Vector3::new(0.0, 0.0, -20.0), Vector3::zeros()).unwrap();
    // Let the rotors settle at their new speeds (≪ 1 s), then compare one rate increment.
    let commands = [hover + 0.02, hover + 0.02, hover - 0.02, hover - 0.02];
    fly(&mut body, 0.3, commands, &far_pad());
    let before = body.state().body_rates_rad_s.z;
    fly(&mut body, 0.1, commands, &far_pad());
    let after = body.state().body_rates_rad_s.z;
    // Independent: yaw torque = Σ KM·T with T = Tmax·u².
    let t_max = p.max_thrust_per_rotor_n;
    let torque =
        0.05 * 2.0 * t_max * (hover + 0.02).powi(2) - 0.05 * 2.0 * t_max * (hover - 0.02).powi(2);
    let expected = torque / 0.055225 * 0.1;
    assert!(
        ((after - before) - expected).abs() < 0.02 * expected,
        "{} vs {expected}",
        after - before
    );
}

#[test]
fn it_rests_on_the_ground_until_the_thrust_lifts_it() {
    let p = QuadrotorParams::default();
    let mut body = Quadrotor::on_ground(p, Vector3::new(3.0, 4.0, 0.0)).unwrap();
    fly(&mut body, 1.0, [0.3; 4], &far_pad());
    assert!(!body.is_flying());
    assert_eq!(body.position_ned_m(), Vector3::new(3.0, 4.0, 0.0));
    assert!((body.state().specific_force_frd_m_s2() - Vector3::new(0.0, 0.0, -G)).norm() < 1e-9);
    fly(&mut body, 1.0, [p.hover_command() + 0.1; 4], &far_pad());
    assert!(body.is_flying());
    assert!(body.position_ned_m().z < -0.1);
    assert!(body.touchdowns().is_empty(), "a take-off is no touchdown");
}

#[test]
fn a_descent_onto_the_moving_pad_is_a_touchdown_and_then_it_rides_along() {
    let p = QuadrotorParams::default();
    let mut pad = PadState {
        centre_ned_m: Vector3::new(0.0, 0.0, -1.5),
        yaw_rad: 0.0,
        velocity_ned_m_s: Vector3::new(1.5, 0.0, 0.0),
        half_size_m: 0.75,
    };
    let mut body =
        Quadrotor::airborne(p, Vector3::new(0.1, 0.2, -3.0), Vector3::new(1.5, 0.0, 0.8)).unwrap();
    let dt = 0.004;
    let mut t = 0.0;
    // A little under hover: it sinks onto the pad, which drives north under it.
    while body.touchdown().is_none() && t < 5.0 {
        t += dt;
        pad.centre_ned_m.x += 1.5 * dt;
        body.set_motor_commands([p.hover_command() - 0.01; 4]);
        body.step(dt, t, Vector3::zeros(), &pad).unwrap();
    }
    let touchdown = body.touchdown().expect("it came down");
    assert!(touchdown.on_pad, "{touchdown:?}");
    assert!(touchdown.vertical_speed_m_s > 0.5, "{touchdown:?}");
    assert!(touchdown.horizontal_error_m < 0.5, "{touchdown:?}");
    // Drag on the way down slows it a little against the pad.
    assert!(
        touchdown.relative_horizontal_speed_m_s < 0.4,
        "{touchdown:?}"
    );
    // Motors at idle: it rides with the pad. The gear's give stops it: the hardest the body
    // is decelerated is about the touchdown speed over the gear's 30 ms (≈ 34 m/s² for
    // 1.03 m/s), nothing like the 1000 m/s² of a stop within one 1 ms sub-step.
    let mut hardest_m_s2: f64 = 0.0;
    for _ in 0..250 {
        t += dt;
        pad.centre_ned_m.x += 1.5 * dt;
        body.set_motor_commands([0.1; 4]);
        body.step(dt, t, Vector3::zeros(), &pad).unwrap();
        hardest_m_s2 = hardest_m_s2.max(body.state().acceleration_ned_m_s2.norm());
    }
    let expected_m_s2 = touchdown.vertical_speed_m_s / 0.03;
    assert!(
        hardest_m_s2 < 1.5 * expected_m_s2 + 10.0,
        "{hardest_m_s2} m/s² against about {expected_m_s2}"
    );
    assert!(!body.is_flying());
    assert!((body.velocity_ned_m_s() - pad.velocity_ned_m_s).norm() < 1e-9);
    assert!((body.position_ned_m().z - pad.centre_ned_m.z).abs() < 1e-12);
    assert_eq!(body.touchdowns().len(), 1);
}

#[test]
fn the_wind_force_pushes_it_downwind() {
    let p = still_air();
    let mut body = Quadrotor::airborne(p, Vector3::new(0.0, 0.0, -20.0), Vector3::zeros()).unwrap();
    let push = Vector3::new(0.0, 3.04, 0.0);
    for i in 0..250 {
        body.step(0.004, (i + 1) as f64 * 0.004, push, &far_pad())
            .unwrap();
    }
    // Independent: v = F/m · t.
    let expected = 3.04 / 1.52 * 1.0;
    assert!((body.velocity_ned_m_s().y - expected).abs() < 1e-6);
}

#[test]
fn bad_inputs_are_named_and_change_nothing() {
    let mut body = Quadrotor::on_ground(QuadrotorParams::default(), Vector3::zeros()).unwrap();
    let before = body.clone();
    assert!(matches!(
        body.step(0.0, 1.0, Vector3::zeros(), &far_pad()),
        Err(QuadrotorError::NotPositive { name: "dt_s", .. })
    ));
    assert!(matches!(
        body.step(0.004, 1.0, Vector3::new(f64::NAN, 0.0, 0.0), &far_pad()),
        Err(QuadrotorError::NonFinite("wind_force_ned_n"))
    ));
    assert_eq!(body, before);
    // A NaN motor command is a stopped motor, not a poisoned state.
    body.set_motor_commands([f64::NAN; 4]);
    assert_eq!(body.motor_commands(), [0.0; 4]);
    body.step(0.004, 0.004, Vector3::zeros(), &far_pad())
        .unwrap();
    assert!(body.position_ned_m().iter().all(|v| v.is_finite()));
    let weak = QuadrotorParams {
        max_thrust_per_rotor_n: 1.0,
        ..QuadrotorParams::default()
    };
    assert!(matches!(
        Quadrotor::on_ground(weak, Vector3::zeros()),
        Err(QuadrotorError::TooWeak { .. })
    ));
}

#[test]
fn px4s_rotor_order_is_ardupilots_quad_x_order_too() {
    // ArduPilot quad X (AP_MotorsMatrix): 1 front right CCW, 2 back left CCW, 3 front left CW,
    // 4 back right CW; a counter-clockwise rotor has KM > 0 in PX4's convention.
    let [fr, bl, fl, br] = QuadrotorParams::default().rotors;
    let sign = |r: Rotor| {
        (
            r.position_frd_m.x.signum(),
            r.position_frd_m.y.signum(),
            r.moment_coefficient_m.signum(),
        )
    };
    assert_eq!(sign(fr), (1.0, 1.0, 1.0));
    assert_eq!(sign(bl), (-1.0, -1.0, 1.0));
    assert_eq!(sign(fl), (1.0, -1.0, -1.0));
    assert_eq!(sign(br), (-1.0, 1.0, -1.0));
}
