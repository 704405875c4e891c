use super::*;

const DT: f64 = 0.005;

fn far_pad() -> PadState {
    PadState {
        centre_ned_m: Vector3::new(1000.0, 1000.0, -1.0),
        yaw_rad: 0.0,
        velocity_ned_m_s: Vector3::zeros(),
        half_size_m: 0.5,
    }
}

fn battery() -> BatteryReading {
    BatteryReading {
        voltage_v: 16.0,
        current_a: 10.0,
        consumed_mah: 0.0,
        remaining_fraction: 1.0,
    }
}

struct Run {
    v: Multirotor,
    t: f64,
}

impl Run {
    fn new() -> Self {
        Self {
            v: Multirotor::on_ground(VehicleParams::default(), Vector3::zeros()).unwrap(),
            t: 0.0,
        }
    }
    fn step(&mut self, force: Vector3<f64>, pad: &PadState) {
        self.t += DT;
        self.v.step(DT, self.t, force, pad).unwrap();
    }
    fn run(&mut self, seconds: f64) {
        for _ in 0..(seconds / DT).round() as usize {
            self.step(Vector3::zeros(), &far_pad());
        }
    }
    fn cmd(&mut self, c: AutopilotCommand) -> Result<(), CommandRejected> {
        self.v.command(c, self.t)
    }
    /// Armed and holding at `altitude_m`.
    fn airborne(altitude_m: f64) -> Self {
        let mut r = Self::new();
        r.cmd(AutopilotCommand::Arm).unwrap();
        r.cmd(AutopilotCommand::Takeoff { altitude_m }).unwrap();
        r.run(altitude_m / 1.5 + 10.0);
        r
    }
    /// Airborne and in Offboard, streaming a zero velocity setpoint.
    fn offboard(altitude_m: f64) -> Self {
        let mut r = Self::airborne(altitude_m);
        r.stream(Vector3::zeros());
        r.cmd(AutopilotCommand::SetMode(FlightMode::Offboard))
            .unwrap();
        r
    }
    fn stream(&mut self, v: Vector3<f64>) {
        self.cmd(AutopilotCommand::VelocitySetpoint {
            velocity_ned_m_s: v,
            yaw_rad: None,
        })
        .unwrap();
    }
}

/// A vehicle holding its place against a steady 8 N of wind leans into it; the camera in
/// its gimbal stays level on the heading, and the snapshot reports where it points.
#[test]
fn a_gimballed_camera_stays_level_while_the_vehicle_leans() {
    let mut r = Run::airborne(10.0);
    r.v =
        r.v.with_gimbal(Gimbal::new(crate::gimbal::GimbalParams::default()).unwrap());
    for _ in 0..(10.0 / DT) as usize {
        r.step(Vector3::new(0.0, 8.0, 0.0), &far_pad());
    }
    assert!(r.v.tilt_rad() > 20f64.to_radians(), "{:?}", r.v.attitude());
    let camera = r.v.camera_pose();
    assert!(camera.attitude.roll_rad.abs() < 1e-3, "{camera:?}");
    assert!(camera.attitude.pitch_rad.abs() < 1e-3, "{camera:?}");
    assert_eq!(camera.attitude.yaw_rad, r.v.attitude().yaw_rad);
    assert_eq!(camera.position_ned_m, r.v.position_ned_m());
    let snap = r.v.snapshot(r.t, battery());
    assert_eq!(snap.gimbal_attitude, Some(camera.attitude));
    // Without a gimbal the camera is the body's, and no gimbal is reported.
    let body = Run::airborne(10.0);
    assert_eq!(body.v.camera_pose().attitude, body.v.attitude());
    assert_eq!(body.v.snapshot(body.t, battery()).gimbal_attitude, None);
}

#[test]
fn hover_holds_altitude() {
    let mut r = Run::airborne(10.0);
    assert_eq!(r.v.mode(), FlightMode::Hold);
    for _ in 0..(30.0 / DT) as usize {
        r.step(Vector3::zeros(), &far_pad());
        assert!((r.v.position_ned_m().z + 10.0).abs() < 0.05);
    }
    // Thrust equals the weight; the vehicle is level.
    assert!((r.v.thrust_n() - 1.5 * GRAVITY_M_S2).abs() < 1e-3);
    assert!(r.v.tilt_rad() < 1e-6);
    assert_eq!(r.v.landed_state(), LandedState::InAir);
    let snap = r.v.snapshot(r.t, battery());
    assert!((snap.rangefinder_m.unwrap() - 10.0).abs() < 0.05);
}

#[test]
fn velocity_step_converges_within_the_tilt_limit() {
    let mut r = Run::offboard(10.0);
    let start = r.t;
    let mut t90 = None;
    let max_tilt = VehicleParams::default().max_tilt_rad;
    for _ in 0..(8.0 / DT) as usize {
        r.stream(Vector3::new(5.0, 0.0, 0.0));
        r.step(Vector3::zeros(), &far_pad());
        assert!(r.v.tilt_rad() <= max_tilt + 1e-9);
        if t90.is_none() && r.v.velocity_ned_m_s().x >= 4.5 {
            t90 = Some(r.t - start);
        }
    }
    let t90 = t90.unwrap();
    // Faster than the tilt limit allows is impossible; slower than the velocity loop's
    // time scale (1/Kp · ln 10 ≈ 1.3 s, plus the attitude lag) would be wrong.
    let physical_bound_s = 4.5 / (GRAVITY_M_S2 * max_tilt.tan());
    assert!(t90 > physical_bound_s && t90 < 2.5, "{t90}");
    assert!((r.v.velocity_ned_m_s() - Vector3::new(5.0, 0.0, 0.0)).norm() < 0.05);
    assert!((r.v.position_ned_m().z + 10.0).abs() < 0.3);
    // Flying level at 5 m/s the vehicle pitches nose down.
    assert!(r.v.attitude().pitch_rad < 0.0);
}

#[test]
fn terminal_speed_matches_the_drag_model() {
    let p = VehicleParams::default();
    let mut r = Run::offboard(20.0);
    // Full tilt north against an 8 N headwind force: m·g·tan(tilt) − 8 = c1·v + c2·v².
    let headwind = Vector3::new(-8.0, 0.0, 0.0);
    for _ in 0..(40.0 / DT) as usize {
        r.stream(Vector3::new(12.0, 0.0, 0.0));
        r.step(headwind, &far_pad());
    }
    let push = p.mass_kg * GRAVITY_M_S2 * p.max_tilt_rad.tan() - 8.0;
    let (c1, c2) = (
        p.drag_linear_horizontal_n_s_per_m,
        p.drag_quadratic_horizontal_n_s2_per_m2,
    );
    let expected = (-c1 + (c1 * c1 + 4.0 * c2 * push).sqrt()) / (2.0 * c2);
    let v = r.v.velocity_ned_m_s().x;
    assert!(expected < 12.0);
    assert!((v / expected - 1.0).abs() < 0.01, "{v} vs {expected}");
}

#[test]
fn offboard_setpoint_timeout_fails_safe_to_hold() {
    let mut r = Run::airborne(5.0);
    assert_eq!(
        r.cmd(AutopilotCommand::SetMode(FlightMode::Offboard)),
        Err(CommandRejected::NoOffboardSetpoint)
    );
    r.stream(Vector3::new(1.0, 0.0, 0.0));
    r.cmd(AutopilotCommand::SetMode(FlightMode::Offboard))
        .unwrap();
    r.run(0.45);
    assert_eq!(r.v.mode(), FlightMode::Offboard);
    r.run(0.1);
    assert_eq!(r.v.mode(), FlightMode::Hold);
    // Hold brakes and stays.
    r.run(10.0);
    assert!(r.v.velocity_ned_m_s().norm() < 0.05);
}

#[test]
fn arming_and_takeoff_rules() {
    let mut r = Run::new();
    assert_eq!(r.v.landed_state(), LandedState::OnGround);
    assert_eq!(
        r.cmd(AutopilotCommand::Takeoff { altitude_m: 5.0 }),
        Err(CommandRejected::NotArmed)
    );
    assert_eq!(
        r.cmd(AutopilotCommand::Land),
        Err(CommandRejected::NotArmed)
    );
    r.cmd(AutopilotCommand::Arm).unwrap();
    assert!(matches!(
        r.cmd(AutopilotCommand::Takeoff { altitude_m: -1.0 }),
        Err(CommandRejected::Invalid(_))
    ));
    assert!(matches!(
        r.cmd(AutopilotCommand::VelocitySetpoint {
            velocity_ned_m_s: Vector3::new(f64::NAN, 0.0, 0.0),
            yaw_rad: None
        }),
        Err(CommandRejected::Invalid(_))
    ));
    // Armed in Hold on the ground: it idles and stays landed.
    r.run(3.0);
    assert!(r.v.is_landed() && r.v.position_ned_m().z == 0.0);
    r.cmd(AutopilotCommand::Takeoff { altitude_m: 5.0 })
        .unwrap();
    r.run(1.0);
    assert_eq!(r.v.landed_state(), LandedState::Takeoff);
    assert_eq!(
        r.cmd(AutopilotCommand::Arm),
        Err(CommandRejected::InAir("arm"))
    );
    assert_eq!(
        r.cmd(AutopilotCommand::Disarm),
        Err(CommandRejected::InAir("disarm"))
    );
    assert_eq!(
        r.cmd(AutopilotCommand::Takeoff { altitude_m: 5.0 }),
        Err(CommandRejected::InAir("take off"))
    );
    assert!(r.v.armed());
}

#[test]
fn takeoff_reaches_its_altitude_at_the_takeoff_speed() {
    let mut r = Run::new();
    r.cmd(AutopilotCommand::Arm).unwrap();
    r.cmd(AutopilotCommand::Takeoff { altitude_m: 6.0 })
        .unwrap();
    let mut fastest_climb: f64 = 0.0;
    for _ in 0..(15.0 / DT) as usize {
        r.step(Vector3::zeros(), &far_pad());
        fastest_climb = fastest_climb.max(-r.v.velocity_ned_m_s().z);
    }
    assert!((r.v.position_ned_m().z + 6.0).abs() < 0.1);
    assert!(r.v.position_ned_m().xy().norm() < 0.05);
    assert_eq!(r.v.mode(), FlightMode::Hold);
    assert_eq!(r.v.landed_state(), LandedState::InAir);
    assert!(
        fastest_climb > 1.3 && fastest_climb < 1.5 * 1.1,
        "{fastest_climb}"
    );
}

#[test]
fn land_descends_at_land_speed_then_detects_landing_and_disarms() {
    let mut r = Run::airborne(8.0);
    r.cmd(AutopilotCommand::Land).unwrap();
    assert_eq!(r.v.landed_state(), LandedState::Landing);
    r.run(5.0);
    assert!((r.v.velocity_ned_m_s().z - 0.7).abs() < 0.02);
    let mut landed_at = None;
    for _ in 0..(20.0 / DT) as usize {
        r.step(Vector3::zeros(), &far_pad());
        if landed_at.is_none() && r.v.is_landed() {
            landed_at = Some(r.t);
        }
    }
    let touchdown = r.v.touchdown().unwrap();
    assert!(!touchdown.on_pad);
    assert!((touchdown.vertical_speed_m_s - 0.7).abs() < 0.05);
    let landed_at = landed_at.unwrap();
    assert!(landed_at - touchdown.time_s >= 0.5 && landed_at - touchdown.time_s < 3.0);
    assert!(!r.v.armed());
    assert_eq!(r.v.landed_state(), LandedState::OnGround);
    assert_eq!(r.v.position_ned_m().z, 0.0);
    // Disarmed on the ground it can arm again.
    r.cmd(AutopilotCommand::Arm).unwrap();
}

fn moving_pad(t: f64) -> PadState {
    PadState {
        centre_ned_m: Vector3::new(1.5 * t, 0.0, -1.0),
        yaw_rad: 0.0,
        velocity_ned_m_s: Vector3::new(1.5, 0.0, 0.0),
        half_size_m: 0.5,
    }
}

/// Offboard chase of the pad with a P controller, descending when over it; `aim_offset_m`
/// aims beside the pad to miss it.
fn land_on_moving_pad(aim_offset_m: Vector2<f64>) -> (Run, Touchdown, PadState) {
    let mut r = Run::offboard(5.0);
    let start = r.t;
    let mut touchdown_pad = None;
    for _ in 0..(60.0 / DT) as usize {
        let pad = moving_pad(r.t - start);
        let error = pad.centre_ned_m.xy() + aim_offset_m - r.v.position_ned_m().xy();
        let xy = pad.velocity_ned_m_s.xy() + error * 1.0;
        let down = if error.norm() < 0.2 { 0.5 } else { 0.0 };
        r.stream(Vector3::new(xy.x, xy.y, down));
        let next = moving_pad(r.t + DT - start);
        r.step(Vector3::zeros(), &next);
        if touchdown_pad.is_none() && r.v.touchdown().is_some() {
            touchdown_pad = Some((next, r.v.position_ned_m()));
        }
    }
    let (pad, position) = touchdown_pad.unwrap();
    // The offset, computed independently from the positions at touchdown.
    let touchdown = r.v.touchdowns()[0];
    let d = position.xy() - pad.centre_ned_m.xy();
    let expected = Vector2::new(d.x, d.y); // pad yaw 0: frames coincide
    assert!((touchdown.offset_in_pad_frame_m - expected).norm() < 1e-9);
    (r, touchdown, pad)
}

#[test]
fn landing_on_a_moving_pad_and_riding_it() {
    let (mut r, touchdown, _) = land_on_moving_pad(Vector2::zeros());
    assert!(touchdown.on_pad, "{touchdown:?}");
    assert!(touchdown.horizontal_error_m < 0.3, "{touchdown:?}");
    assert!(touchdown.relative_horizontal_speed_m_s < 0.3);
    assert!(touchdown.vertical_speed_m_s > 0.3);
    assert!(r.v.on_pad_now());
    // Riding: 20 s later it is still at the same place on the pad, at its height, at its speed.
    let start = r.t - 60.0;
    for _ in 0..(20.0 / DT) as usize {
        r.stream(Vector3::zeros());
        let next = moving_pad(r.t + DT - start);
        r.step(Vector3::zeros(), &next);
    }
    let pad = moving_pad(r.t - start);
    let offset = r.v.position_ned_m().xy() - pad.centre_ned_m.xy();
    assert!((offset - touchdown.offset_in_pad_frame_m).norm() < 1e-9);
    assert_eq!(r.v.position_ned_m().z, -1.0);
    assert!((r.v.velocity_ned_m_s() - pad.velocity_ned_m_s).norm() < 1e-9);
    let snap = r.v.snapshot(r.t, battery());
    assert_eq!(snap.rangefinder_m, None); // 0 m to the pad: below the minimum range
}

#[test]
fn a_pad_rising_into_a_descending_vehicle_is_a_landing_on_it() {
    let mut r = Run::offboard(5.0);
    let below = r.v.position_ned_m().xy();
    let pad_at = |top_down_m: f64| PadState {
        centre_ned_m: Vector3::new(below.x, below.y, top_down_m),
        yaw_rad: 0.0,
        velocity_ned_m_s: Vector3::zeros(),
        half_size_m: 0.5,
    };
    // Down to a centimetre or two above the pad's top, slowly.
    while r.v.position_ned_m().z < -1.02 {
        let down_m_s = if r.v.position_ned_m().z < -1.5 {
            1.0
        } else {
            0.3
        };
        r.stream(Vector3::new(0.0, 0.0, down_m_s));
        r.step(Vector3::zeros(), &pad_at(-1.0));
        assert!(r.v.touchdown().is_none());
    }
    assert!(r.v.position_ned_m().z < -1.0);
    // A heave lifts the top 5 cm within one step: past the vehicle, which never crosses it
    // from above within the step.
    r.stream(Vector3::new(0.0, 0.0, 0.3));
    r.step(Vector3::zeros(), &pad_at(-1.05));
    let touchdown = r.v.touchdown().expect("a touchdown");
    assert!(touchdown.on_pad, "{touchdown:?}");
    assert!(r.v.on_pad_now());
}

#[test]
fn missing_the_pad_lands_on_the_ground() {
    let (r, touchdown, _) = land_on_moving_pad(Vector2::new(0.0, 2.0));
    assert!(!touchdown.on_pad);
    assert!((touchdown.offset_in_pad_frame_m.y - 2.0).abs() < 0.25);
    assert!(r.v.touchdowns().iter().all(|t| !t.on_pad));
    // The ground does not move: relative speed is the vehicle's own.
    assert!((touchdown.relative_horizontal_speed_m_s - 1.5).abs() < 0.3);
}

#[test]
fn starting_on_a_turning_pad_then_taking_off() {
    use crate::tractor::{PathKind, Tractor, TractorParams};
    let mut tractor =
        Tractor::new(PathKind::Circle, TractorParams::default(), [0.0, 0.0], 0.0).unwrap();
    let offset = Vector2::new(0.2, -0.1);
    let mut v = Multirotor::on_pad(VehicleParams::default(), &tractor.pad(), offset).unwrap();
    let mut t = 0.0;
    let step = |v: &mut Multirotor, tractor: &mut Tractor, t: &mut f64| {
        tractor.step(DT).unwrap();
        *t += DT;
        v.step(DT, *t, Vector3::zeros(), &tractor.pad()).unwrap();
    };
    for _ in 0..(10.0 / DT) as usize {
        step(&mut v, &mut tractor, &mut t);
    }
    let pad = tractor.pad();
    // Rides at its place on the turning pad, facing with it.
    assert!((pad.to_pad_frame(v.position_ned_m().xy()) - offset).norm() < 1e-9);
    assert!(wrap_angle(v.attitude().yaw_rad - pad.yaw_rad).abs() < 1e-9);
    assert!(pad.yaw_rad.abs() > 0.5);
    assert!(v.touchdowns().is_empty());
    v.command(AutopilotCommand::Arm, t).unwrap();
    v.command(AutopilotCommand::Takeoff { altitude_m: 3.0 }, t)
        .unwrap();
    for _ in 0..(12.0 / DT) as usize {
        step(&mut v, &mut tractor, &mut t);
    }
    assert!(v.is_flying() && !v.is_landed());
    assert!(
        (v.position_ned_m().z + 4.0).abs() < 0.1,
        "{:?}",
        v.position_ned_m()
    );
    assert!(v.touchdowns().is_empty());
    let snap = v.snapshot(t, battery());
    assert!(snap.armed && snap.mode == FlightMode::Hold);
}

#[test]
fn bad_parameters_and_inputs_are_refused() {
    let p = VehicleParams {
        max_thrust_n: 10.0,
        ..VehicleParams::default()
    };
    assert!(matches!(p.validate(), Err(VehicleError::TooWeak { .. })));
    let p = VehicleParams {
        mass_kg: f64::NAN,
        ..VehicleParams::default()
    };
    assert!(matches!(
        p.validate(),
        Err(VehicleError::NotPositive {
            name: "mass_kg",
            ..
        })
    ));
    let mut r = Run::new();
    let before = r.v.clone();
    assert!(r.v.step(0.0, 1.0, Vector3::zeros(), &far_pad()).is_err());
    assert!(r
        .v
        .step(DT, 1.0, Vector3::new(f64::NAN, 0.0, 0.0), &far_pad())
        .is_err());
    assert_eq!(r.v, before);
}
