use super::*;

mod follow;
mod wind;

const DT_S: f64 = 0.05;

fn fix_at(north_m: f64, east_m: f64, height_m: f64) -> Option<RelativeFix> {
    Some(RelativeFix::with_std(
        Vector3::new(north_m, east_m, -height_m),
        0.02,
    ))
}

fn input(time_s: f64, fix: Option<RelativeFix>, height_m: f64) -> LandingInput {
    LandingInput {
        time_s,
        fix,
        height_above_pad_m: height_m,
        platform_velocity_ne_m_s: Vector2::new(3.0, 0.0),
        touchdown_detected: false,
        uav_velocity_ne_m_s: Vector2::new(3.0, 0.0),
        descent_allowed: true,
        predicted_uav_minus_pad_ne_m: None,
        setpoints_followed: true,
        pad_in_view_offset_per_height: Vector2::zeros(),
        near_ground_wind: None,
    }
}

/// Steps at DT_S from `t_s` for `duration_s` with the same fix offset and height; returns
/// the last output and the time after.
fn run(
    c: &mut LandingController,
    t_s: &mut f64,
    duration_s: f64,
    offset_m: Option<f64>,
    height_m: f64,
) -> LandingOutput {
    let steps = (duration_s / DT_S).round() as usize;
    let mut out = None;
    for _ in 0..steps.max(1) {
        *t_s += DT_S;
        let fix = offset_m.and_then(|o| fix_at(o, 0.0, height_m));
        out = Some(c.step(&input(*t_s, fix, height_m)).unwrap());
    }
    out.unwrap()
}

/// The reference mission's close-in PID (8/s and 2.5) and final descent (2 m/s).
fn close_in_config() -> LandingConfig {
    let mut pid = PidConfig::default();
    pid.gains.low.kp_per_s = 8.0;
    pid.gains.low.kd = 2.5;
    LandingConfig {
        final_descent_speed_m_s: 2.0,
        pid,
        ..LandingConfig::default()
    }
}

/// A controller brought to Descend at IH with the target centred.
fn descending() -> (LandingController, f64) {
    descending_with(LandingConfig::default())
}

fn descending_with(config: LandingConfig) -> (LandingController, f64) {
    let mut c = LandingController::new(config).unwrap();
    let mut t_s = 0.0;
    let out = run(&mut c, &mut t_s, 1.0, Some(0.0), 7.5);
    assert_eq!(out.mode, LandingMode::Descend);
    (c, t_s)
}

#[test]
fn defaults_are_the_seed_altitudes() {
    let config = LandingConfig::default();
    assert_eq!(config.initial_height_m, 7.5);
    assert_eq!(config.final_landing_height_m, 1.5);
    assert!(config.validate().is_ok());
}

#[test]
fn search_holds_at_ih_until_a_fix() {
    let mut c = LandingController::new(LandingConfig::default()).unwrap();
    let mut t_s = 0.0;
    let out = run(&mut c, &mut t_s, 2.0, None, 5.0);
    assert_eq!(out.mode, LandingMode::Search);
    assert_eq!(out.velocity_setpoint_ned_m_s.xy(), Vector2::zeros());
    // 2.5 m below IH: climb (NED down negative) at the hold limit.
    assert_eq!(out.velocity_setpoint_ned_m_s.z, -1.0);
    assert!(!out.land_command);
    let out = run(&mut c, &mut t_s, DT_S, Some(2.0), 5.0);
    assert_eq!(out.mode, LandingMode::Follow);
}

#[test]
fn follow_descends_only_at_ih_and_centred_for_the_dwell() {
    let mut c = LandingController::new(LandingConfig::default()).unwrap();
    let mut t_s = 0.0;
    // Centred but still climbing to IH: stays in Follow and climbs.
    let out = run(&mut c, &mut t_s, 2.0, Some(0.0), 5.0);
    assert_eq!(out.mode, LandingMode::Follow);
    assert!(out.velocity_setpoint_ned_m_s.z < 0.0);
    // At IH but 1.5 m off centre (radius at IH is 1.0 m): stays.
    let out = run(&mut c, &mut t_s, 2.0, Some(1.5), 7.5);
    assert_eq!(out.mode, LandingMode::Follow);
    // The PID pulls towards the pad on top of the platform's 3 m/s: uav is north of the
    // pad, so the north velocity is below 3 m/s.
    assert!(out.velocity_setpoint_ned_m_s.x < 3.0);
    // Centred: not before the 0.5 s dwell …
    let out = run(&mut c, &mut t_s, 0.4, Some(0.5), 7.5);
    assert_eq!(out.mode, LandingMode::Follow);
    // … then Descend, going down at the descent speed.
    let out = run(&mut c, &mut t_s, 0.2, Some(0.5), 7.5);
    assert_eq!(out.mode, LandingMode::Descend);
    assert_eq!(out.velocity_setpoint_ned_m_s.z, 0.7);
}

#[test]
fn centred_threshold_tightens_with_altitude() {
    let config = LandingConfig::default();
    assert_eq!(config.centred_radius_m(7.5), 1.0);
    assert_eq!(config.centred_radius_m(20.0), 1.0);
    assert_eq!(config.centred_radius_m(1.5), 0.15);
    assert_eq!(config.centred_radius_m(0.2), 0.15);
    assert!((config.centred_radius_m(4.5) - 0.575).abs() < 1e-12);

    // 0.5 m off is centred at 7.5 m but not at 3 m (radius 0.3625 m): the descent stops,
    // and at 2 × the radius it goes back to Follow holding its height.
    let (mut c, mut t_s) = descending();
    let out = run(&mut c, &mut t_s, DT_S, Some(0.5), 3.0);
    assert_eq!(out.mode, LandingMode::Descend);
    assert_eq!(out.velocity_setpoint_ned_m_s.z, 0.0);
    let out = run(&mut c, &mut t_s, DT_S, Some(0.8), 3.0);
    assert_eq!(out.mode, LandingMode::Follow);
    assert_eq!(out.velocity_setpoint_ned_m_s.z, 0.0);
}

#[test]
fn commit_below_lh_then_landed() {
    let (mut c, mut t_s) = descending();
    // Above LH: no commit however centred.
    let out = run(&mut c, &mut t_s, 1.0, Some(0.0), 1.6);
    assert_eq!(out.mode, LandingMode::Descend);
    // Below LH but 0.2 m off (radius 0.15 m): no commit.
    let out = run(&mut c, &mut t_s, 1.0, Some(0.2), 1.4);
    assert_eq!(out.mode, LandingMode::Descend);
    // Centred below LH: commit after the 0.3 s dwell.
    let out = run(&mut c, &mut t_s, 0.2, Some(0.05), 1.4);
    assert_eq!(out.mode, LandingMode::Descend);
    let out = run(&mut c, &mut t_s, 0.2, Some(0.05), 1.4);
    assert_eq!(out.mode, LandingMode::FinalLanding);
    assert!(out.land_command);
    assert_eq!(out.velocity_setpoint_ned_m_s.z, 1.0);
    // Still steering horizontally: about the platform's velocity.
    assert!((out.velocity_setpoint_ned_m_s.x - 3.0).abs() < 0.2);
    let out = run(&mut c, &mut t_s, DT_S, Some(0.0), 0.04);
    assert_eq!(out.mode, LandingMode::Landed);
    assert!(out.land_command);
    // Down: it rides with the platform, pressing onto the pad, until the autopilot takes over.
    let v = out.velocity_setpoint_ned_m_s;
    assert!((v.x - 3.0).abs() < 0.2 && v.y.abs() < 0.2, "{v}");
    assert_eq!(v.z, 1.0);
}

/// Committed and descending at the final speed, the vehicle meets the pad 0.1 m above
/// where it thought the pad was (the estimate's bias): the height stops falling, and within
/// a few steps the landing counts as done, before the autopilot's land detector says so.
/// A descent still under way that low is not a touchdown.
#[test]
fn a_descent_stopped_by_the_pad_is_the_touchdown() {
    let (mut c, mut t_s) = descending();
    let lh_m = c.config().final_landing_height_m;
    assert_eq!(
        run(&mut c, &mut t_s, 1.0, Some(0.0), lh_m).mode,
        LandingMode::FinalLanding
    );
    let speed_m_s = c.config().final_descent_speed_m_s;
    let mut height_m = lh_m;
    while height_m > 0.12 {
        height_m -= speed_m_s * DT_S;
        let out = run(&mut c, &mut t_s, DT_S, Some(0.0), height_m);
        assert_eq!(out.mode, LandingMode::FinalLanding, "at {height_m} m");
    }
    let mut steps = 0;
    while run(&mut c, &mut t_s, DT_S, Some(0.0), 0.1).mode != LandingMode::Landed {
        steps += 1;
        assert!(steps < 4, "still not landed after {steps} steps on the pad");
    }
}

/// The reference mission's descent after the commit, flown by an autopilot whose vertical
/// velocity follows the command with a 0.25 s first-order lag, from LH to the pad; returns the
/// vertical speed at contact and the time taken.
fn fly_the_final_descent(config: LandingConfig) -> (f64, f64) {
    const STEP_S: f64 = 0.01;
    const LAG_S: f64 = 0.25;
    let (mut c, mut t_s) = descending_with(config);
    let lh_m = config.final_landing_height_m;
    assert_eq!(
        run(&mut c, &mut t_s, 1.0, Some(0.0), lh_m).mode,
        LandingMode::FinalLanding
    );
    let (mut height_m, mut down_m_s, start_s) = (lh_m, 0.0, t_s);
    while height_m > 0.0 {
        t_s += STEP_S;
        let out = c
            .step(&input(t_s, fix_at(0.0, 0.0, height_m), height_m))
            .unwrap();
        let command_m_s = out.velocity_setpoint_ned_m_s.z;
        down_m_s += (command_m_s - down_m_s) * STEP_S / LAG_S;
        height_m -= down_m_s * STEP_S;
        assert!(t_s - start_s < 10.0, "no contact: {out:?} at {height_m} m");
    }
    (down_m_s, t_s - start_s)
}

/// The flare brings a quick committed descent down softly: with it the lagging autopilot meets
/// the pad at no more than the touchdown speed plus a little of its lag, without it at nearly
/// the full 2 m/s; the flare costs well under a second.
#[test]
fn the_flare_meets_the_pad_softly() {
    let flared = LandingConfig {
        flare_deceleration_m_s2: 2.5,
        touchdown_speed_m_s: 0.6,
        flare_lead_s: 0.25,
        ..close_in_config()
    };
    let (plain_m_s, plain_s) = fly_the_final_descent(close_in_config());
    let (flared_m_s, flared_s) = fly_the_final_descent(flared);
    assert!(
        plain_m_s > 1.8,
        "{plain_m_s} m/s at contact without the flare"
    );
    assert!(
        flared_m_s > 0.5 && flared_m_s < 0.8,
        "{flared_m_s} m/s at contact with the flare"
    );
    assert!(
        flared_s > plain_s && flared_s < plain_s + 0.8,
        "{flared_s} s against {plain_s} s"
    );
    // Without its lead, the same profile is followed late and meets the pad faster.
    let late = LandingConfig {
        flare_lead_s: 0.0,
        ..flared
    };
    let (late_m_s, _) = fly_the_final_descent(late);
    assert!(
        late_m_s > flared_m_s + 0.2,
        "{late_m_s} against {flared_m_s}"
    );
}

/// The profile itself: the final speed high up, the touchdown speed at the pad, and in
/// between the speed a constant deceleration leaves (v² = v_td² + 2·a·h).
#[test]
fn the_flare_profile_is_a_constant_deceleration() {
    let config = LandingConfig {
        final_descent_speed_m_s: 2.0,
        flare_deceleration_m_s2: 2.0,
        touchdown_speed_m_s: 0.5,
        flare_lead_s: 0.2,
        ..LandingConfig::default()
    };
    assert_eq!(config.final_descent_rate_m_s(1.5, 0.0), 2.0);
    assert_eq!(config.final_descent_rate_m_s(0.0, 1.0), 0.5);
    // 0.3 m up, descending at 1 m/s: read 0.2 m further down, at 0.1 m.
    let expected_m_s = (0.25_f64 + 2.0 * 2.0 * 0.1).sqrt();
    assert!((config.final_descent_rate_m_s(0.3, 1.0) - expected_m_s).abs() < 1e-12);
    let off = LandingConfig {
        flare_deceleration_m_s2: 0.0,
        ..config
    };
    assert_eq!(off.final_descent_rate_m_s(0.1, 1.0), 2.0);
}

#[test]
fn autopilot_touchdown_means_landed() {
    let (mut c, mut t_s) = descending();
    t_s += DT_S;
    let mut i = input(t_s, fix_at(0.0, 0.0, 3.0), 3.0);
    i.touchdown_detected = true;
    assert_eq!(c.step(&i).unwrap().mode, LandingMode::Landed);
}

#[test]
fn lost_target_aborts_and_climbs_back_to_ih() {
    let (mut c, mut t_s) = descending();
    run(&mut c, &mut t_s, 2.0, Some(0.0), 4.0);
    // A dropout shorter than the 1 s timeout: keep descending mode, hold height, feed the
    // platform's velocity forward.
    let out = run(&mut c, &mut t_s, 0.9, None, 4.0);
    assert_eq!(out.mode, LandingMode::Descend);
    assert_eq!(out.velocity_setpoint_ned_m_s.z, 0.0);
    assert!((out.velocity_setpoint_ned_m_s.x - 3.0).abs() < 1e-9);
    // Past the timeout: Reacquire, climbing towards IH.
    let out = run(&mut c, &mut t_s, 0.2, None, 4.0);
    assert_eq!(out.mode, LandingMode::Reacquire);
    assert_eq!(out.velocity_setpoint_ned_m_s.z, -1.0);
    assert!(!out.land_command);
    // With the tracker's prediction of where the pad went, Reacquire flies towards it:
    // 0.5 /s of the offset on top of the platform's 3 m/s, at most 3 m/s more.
    for (behind_m, expected_m_s) in [(2.0, 4.0), (10.0, 6.0)] {
        t_s += DT_S;
        let mut i = input(t_s, None, 4.0);
        i.predicted_uav_minus_pad_ne_m = Some(Vector2::new(-behind_m, 0.0));
        let out = c.step(&i).unwrap();
        assert_eq!(out.mode, LandingMode::Reacquire);
        assert!(
            (out.velocity_setpoint_ned_m_s.x - expected_m_s).abs() < 1e-9,
            "{out:?}"
        );
    }
    // Seen again: Follow, holding IH.
    let out = run(&mut c, &mut t_s, DT_S, Some(0.0), 5.0);
    assert_eq!(out.mode, LandingMode::Follow);
    assert!(out.velocity_setpoint_ned_m_s.z < 0.0);
    // Lost for longer than the search timeout: Search.
    let out = run(&mut c, &mut t_s, 1.5, None, 7.5);
    assert_eq!(out.mode, LandingMode::Reacquire);
    let out = run(&mut c, &mut t_s, 9.0, None, 7.5);
    assert_eq!(out.mode, LandingMode::Search);
    assert_eq!(out.velocity_setpoint_ned_m_s.xy(), Vector2::zeros());
}

#[test]
fn an_uncertain_or_nan_fix_counts_as_lost() {
    let (mut c, mut t_s) = descending();
    for k in 0..30 {
        t_s += DT_S;
        let fix = if k % 2 == 0 {
            Some(RelativeFix::with_std(Vector3::new(0.0, 0.0, -7.0), 1.0))
        } else {
            Some(RelativeFix::with_std(
                Vector3::new(f64::NAN, 0.0, -7.0),
                0.02,
            ))
        };
        let out = c.step(&input(t_s, fix, 7.0)).unwrap();
        assert_eq!(out.horizontal_error_m, None);
    }
    assert_eq!(c.mode(), LandingMode::Reacquire);
}

#[test]
fn no_abort_after_commit() {
    let (mut c, mut t_s) = descending();
    run(&mut c, &mut t_s, 0.5, Some(0.0), 1.4);
    assert_eq!(c.mode(), LandingMode::FinalLanding);
    // The pad fills the view and the target is lost for 10 s: still landing.
    let out = run(&mut c, &mut t_s, 10.0, None, 0.5);
    assert_eq!(out.mode, LandingMode::FinalLanding);
    assert!(out.land_command);
    assert_eq!(out.velocity_setpoint_ned_m_s.z, 1.0);
    assert!((out.velocity_setpoint_ned_m_s.x - 3.0).abs() < 1e-9);
    // Nor does an off-centre fix undo it.
    let out = run(&mut c, &mut t_s, 1.0, Some(2.0), 0.5);
    assert_eq!(out.mode, LandingMode::FinalLanding);
}

#[test]
fn platform_acceleration_is_fed_forward() {
    let mut c = LandingController::new(LandingConfig::default()).unwrap();
    let mut t_s = 0.0;
    run(&mut c, &mut t_s, 1.0, Some(0.0), 7.5);
    // The platform speeds up east at 1 m/s²; with no fix the setpoint is the platform's
    // velocity plus (filtered) acceleration × 0.2 s lead.
    let mut out = None;
    for k in 1..=60 {
        t_s += DT_S;
        let mut i = input(t_s, fix_at(0.0, 0.0, 7.5), 7.5);
        i.platform_velocity_ne_m_s = Vector2::new(3.0, k as f64 * DT_S);
        out = Some(c.step(&i).unwrap());
    }
    let out = out.unwrap();
    let east_platform_m_s = 60.0 * DT_S;
    let lead_m_s = out.velocity_setpoint_ned_m_s.y - east_platform_m_s;
    assert!((lead_m_s - 0.2).abs() < 0.01, "lead {lead_m_s}");
}

#[test]
fn bad_input_is_an_error_and_changes_nothing() {
    let (mut c, t_s) = descending();
    let before = c.machine.clone();
    let mut i = input(t_s + DT_S, fix_at(0.0, 0.0, 5.0), 5.0);
    i.uav_velocity_ne_m_s.y = f64::NAN;
    assert!(matches!(c.step(&i), Err(LandingError::NonFinite { .. })));
    i.uav_velocity_ne_m_s.y = 0.0;
    i.time_s = f64::NAN;
    assert_eq!(c.step(&i), Err(LandingError::NonFinite { name: "time_s" }));
    let mut i = input(t_s + DT_S, None, f64::NAN);
    assert!(matches!(c.step(&i), Err(LandingError::NonFinite { .. })));
    i.height_above_pad_m = 5.0;
    i.platform_velocity_ne_m_s.x = f64::INFINITY;
    assert!(matches!(c.step(&i), Err(LandingError::NonFinite { .. })));
    assert!(matches!(
        c.step(&input(t_s, None, 5.0)),
        Err(LandingError::TimeNotIncreasing { .. })
    ));
    assert_eq!(c.machine, before);
    let hover = LandingOutput::hover(c.mode());
    assert_eq!(hover.velocity_setpoint_ned_m_s, Vector3::zeros());
    assert!(!hover.land_command);
    assert!(LandingOutput::hover(LandingMode::FinalLanding).land_command);
}

/// A vehicle that starts on the ground reports touchdown; once it is airborne above LH
/// the procedure starts over from Search, and finds the target again.
#[test]
fn a_take_off_after_landed_starts_over() {
    let mut c = LandingController::new(LandingConfig::default()).unwrap();
    let mut on_ground = input(0.0, None, 0.0);
    on_ground.touchdown_detected = true;
    assert_eq!(c.step(&on_ground).unwrap().mode, LandingMode::Landed);
    // Climbing through 1 m (below LH): still Landed, nothing commanded.
    let climbing = input(1.0, None, 1.0);
    assert_eq!(c.step(&climbing).unwrap().mode, LandingMode::Landed);
    // Above LH 5 s after the last touchdown report: a height estimate's jump near the pad
    // for all it knows, so still Landed; 6 s on, a take-off.
    let airborne = input(5.0, None, 5.0);
    assert_eq!(c.step(&airborne).unwrap().mode, LandingMode::Landed);
    let airborne = input(6.0, None, 5.5);
    assert_eq!(c.step(&airborne).unwrap().mode, LandingMode::Search);
    let seen = input(6.1, fix_at(0.5, 0.0, 7.5), 7.5);
    assert_eq!(c.step(&seen).unwrap().mode, LandingMode::Follow);
}

#[test]
fn bad_config_is_named() {
    let config = LandingConfig {
        final_landing_height_m: 8.0,
        ..LandingConfig::default()
    };
    assert!(matches!(
        LandingController::new(config),
        Err(LandingError::Config {
            name: "final_landing_height_m",
            ..
        })
    ));
    let config = LandingConfig {
        lost_timeout_s: f64::NAN,
        ..LandingConfig::default()
    };
    assert!(matches!(
        LandingController::new(config),
        Err(LandingError::Config {
            name: "lost_timeout_s",
            ..
        })
    ));
    let config = LandingConfig {
        keep_in_view_tau_s: -1.0,
        ..LandingConfig::default()
    };
    assert!(matches!(
        LandingController::new(config),
        Err(LandingError::Config {
            name: "keep_in_view_tau_s",
            ..
        })
    ));
    // A non-finite keep-in-view offset is refused and leaves the machine as it was.
    let mut c = LandingController::new(LandingConfig::default()).unwrap();
    let bad = LandingInput {
        pad_in_view_offset_per_height: Vector2::new(f64::NAN, 0.0),
        ..input(0.1, None, 7.5)
    };
    assert_eq!(
        c.step(&bad),
        Err(LandingError::NonFinite {
            name: "pad_in_view_offset_per_height"
        })
    );
    assert!(c.step(&input(0.1, None, 7.5)).is_ok());
    let mut config = LandingConfig::default();
    config.pid.max_ctrl_speed_m_s = -1.0;
    assert!(matches!(
        LandingController::new(config),
        Err(LandingError::Pid(_))
    ));
}
