use super::*;

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

/// A vehicle leaning so far that its camera sees the pad only west of it (pad − UAV
/// = (0, −0.15)·height): it follows east of the pad by that much, descends, and the offset
/// shrinks with height so that it touches down on the pad. The vehicle flies the commands
/// with the autopilot's lag; the platform drives north at 1.5 m/s.
#[test]
fn a_leaning_vehicle_follows_where_its_camera_sees_the_pad_and_lands_on_it() {
    let per_height = Vector2::new(0.0, -0.15);
    let mut c = LandingController::new(LandingConfig::default()).unwrap();
    let platform = Vector2::new(1.5, 0.0);
    let (mut uav, mut pad) = (Vector2::new(0.0, 0.0), Vector2::new(0.5, 0.0));
    let (mut velocity, mut height_m) = (platform, 7.5);
    let tau_s = LandingConfig::default().autopilot_velocity_tau_s;
    let mut checked_at_4_m = false;
    for step in 1..=1200 {
        let t_s = step as f64 * DT_S;
        let out = c
            .step(&LandingInput {
                uav_velocity_ne_m_s: velocity,
                platform_velocity_ne_m_s: platform,
                pad_in_view_offset_per_height: per_height,
                ..input(
                    t_s,
                    fix_at((uav - pad).x, (uav - pad).y, height_m),
                    height_m,
                )
            })
            .unwrap();
        if out.mode == LandingMode::Landed {
            // The PID trails the setpoint sliding towards the pad with the descent (by
            // ~0.15 m at 4 m, less as the slide slows near the pad). Feeding the slide's
            // rate forward halved this here but flew worse in the realistic world's gusts.
            assert!(
                (uav - pad).norm() < 0.15,
                "landed {} m off",
                (uav - pad).norm()
            );
            assert!(checked_at_4_m);
            return;
        }
        if out.mode == LandingMode::Descend && (height_m - 4.0).abs() < 0.05 {
            let want = -per_height * height_m;
            assert!(
                ((uav - pad) - want).norm() < 0.2,
                "at {height_m} m: {} vs {want}",
                uav - pad
            );
            checked_at_4_m = true;
        }
        let command = out.velocity_setpoint_ned_m_s;
        velocity += (command.xy() - velocity) * (DT_S / (tau_s + DT_S));
        uav += velocity * DT_S;
        pad += platform * DT_S;
        height_m = (height_m - command.z * DT_S).max(0.0);
    }
    panic!("never landed");
}

/// Knocked off centre below LH before the commit: the vehicle follows again from LH,
/// climbing, not from where the gust caught it; centred there, it descends and commits.
#[test]
fn a_recentre_below_the_commit_height_climbs_back_to_it() {
    let (mut c, mut t_s) = descending();
    let lh_m = LandingConfig::default().final_landing_height_m;
    let low_m = 0.8 * lh_m;
    let out = run(&mut c, &mut t_s, DT_S, Some(0.6), low_m);
    assert_eq!(out.mode, LandingMode::Follow);
    assert!(
        out.velocity_setpoint_ned_m_s.z < -0.1,
        "climbs: {}",
        out.velocity_setpoint_ned_m_s.z
    );
    // A recentre above LH holds the height it was caught at, as before.
    let (mut above, mut t_above_s) = descending();
    let out = run(&mut above, &mut t_above_s, DT_S, Some(2.5), 4.0);
    assert_eq!(out.mode, LandingMode::Follow);
    assert!(out.velocity_setpoint_ned_m_s.z.abs() < 1e-9);
    // Back at LH and centred: down again, and committed after its dwell.
    let out = run(&mut c, &mut t_s, 1.0, Some(0.0), lh_m);
    assert_eq!(out.mode, LandingMode::FinalLanding);
}

/// Committed, 0.8 m north of the pad: the command strays from the platform's velocity
/// towards the pad by at most the final correction, and by at most the touchdown one in the
/// last centimetres (the band by height alone: the heights here are set, not flown).
#[test]
fn in_the_last_centimetres_the_correction_is_bounded() {
    let config = LandingConfig {
        touchdown_correction_lead_s: 0.0,
        ..LandingConfig::default()
    };
    let committed_then_off_centre = |height_m: f64| {
        let (mut c, mut t_s) = descending_with(config);
        let lh_m = c.config().final_landing_height_m;
        assert_eq!(
            run(&mut c, &mut t_s, 1.0, Some(0.0), lh_m).mode,
            LandingMode::FinalLanding
        );
        let out = run(&mut c, &mut t_s, DT_S, Some(0.8), height_m);
        assert_eq!(out.mode, LandingMode::FinalLanding);
        let platform = input(0.0, None, 0.0).platform_velocity_ne_m_s;
        out.velocity_setpoint_ned_m_s.xy() - platform
    };
    // The PID asks for more than either limit (1.5/s × 0.8 m alone).
    let above = committed_then_off_centre(config.touchdown_correction_height_m + 0.2);
    assert!(
        (above.norm() - config.max_final_correction_m_s).abs() < 1e-12,
        "{above:?}"
    );
    assert!(above.x < 0.0 && above.y.abs() < 1e-12, "{above:?}");
    let within = committed_then_off_centre(0.5 * config.touchdown_correction_height_m);
    assert!(
        (within.norm() - config.max_touchdown_correction_m_s).abs() < 1e-12,
        "{within:?}"
    );
    assert!(within.x < 0.0 && within.y.abs() < 1e-12, "{within:?}");
}

/// Flown down at 2 m/s after the commit, 0.8 m north of the pad: the small corrections
/// begin `touchdown_correction_lead_s` before contact at the descent's rate (0.8 m up), not
/// at `touchdown_correction_height_m` (0.3 m).
#[test]
fn a_fast_descent_enters_the_touchdown_band_early() {
    let config = LandingConfig {
        touchdown_correction_lead_s: 0.4,
        ..close_in_config()
    };
    let band_m = config.final_descent_speed_m_s * config.touchdown_correction_lead_s;
    assert!(
        band_m > config.touchdown_correction_height_m + 0.3,
        "{band_m}"
    );
    let (mut c, mut t_s) = descending_with(config);
    let lh_m = config.final_landing_height_m;
    assert_eq!(
        run(&mut c, &mut t_s, 1.0, Some(0.0), lh_m).mode,
        LandingMode::FinalLanding
    );
    let platform = input(0.0, None, 0.0).platform_velocity_ne_m_s;
    let (mut height_m, mut above, mut within) = (lh_m, 0, 0);
    loop {
        t_s += DT_S;
        let out = c
            .step(&input(t_s, fix_at(0.8, 0.0, height_m), height_m))
            .unwrap();
        if out.mode != LandingMode::FinalLanding {
            break;
        }
        let correction = out.velocity_setpoint_ned_m_s.xy() - platform;
        assert!(correction.x < 0.0, "{correction:?} at {height_m} m");
        // A margin of one step either side of the band's edge, and the first steps after the
        // commit, while the measured descent rate settles.
        if height_m > band_m + 0.15 && height_m < lh_m - 0.25 {
            above += 1;
            let excess = correction.norm() - config.max_final_correction_m_s;
            assert!(excess.abs() < 1e-9, "{correction:?} at {height_m} m");
        } else if height_m < band_m - 0.15 {
            within += 1;
            let excess = correction.norm() - config.max_touchdown_correction_m_s;
            assert!(excess.abs() < 1e-9, "{correction:?} at {height_m} m");
        }
        height_m -= out.velocity_setpoint_ned_m_s.z * DT_S;
    }
    assert!(
        above >= 2 && within >= 3,
        "{above} steps above, {within} within"
    );
}

/// Searching with no fix, the same lean: the vehicle moves upwind until its camera sees
/// the spot it began over, and holds there.
#[test]
fn a_leaning_vehicle_searches_where_it_began() {
    let per_height = Vector2::new(0.0, -0.2);
    let mut c = LandingController::new(LandingConfig::default()).unwrap();
    let (mut moved, mut velocity) = (Vector2::zeros(), Vector2::zeros());
    for step in 1..=400 {
        let out = c
            .step(&LandingInput {
                uav_velocity_ne_m_s: velocity,
                platform_velocity_ne_m_s: Vector2::zeros(),
                pad_in_view_offset_per_height: per_height,
                ..input(step as f64 * DT_S, None, 7.5)
            })
            .unwrap();
        assert_eq!(out.mode, LandingMode::Search);
        velocity = out.velocity_setpoint_ned_m_s.xy();
        moved += velocity * DT_S;
    }
    let want = -per_height * 7.5;
    assert!((moved - want).norm() < 0.05, "moved {moved}, want {want}");
}

/// An autopilot that falls 0.8 m/s short of every command (a wind its integrator does not
/// hold): with the feed-forward, the vehicle's true velocity comes to what the guidance
/// wants; without it, it stays 0.8 m/s short. The vehicle is simulated here as exactly
/// that: the command, lagged by the configured response, minus the shortfall.
#[test]
fn wind_feed_forward_makes_up_the_autopilots_shortfall() {
    let shortfall = Vector2::new(0.8, -0.3);
    let fly = |tau_s: f64| {
        let config = LandingConfig {
            wind_compensation_tau_s: tau_s,
            ..LandingConfig::default()
        };
        let mut c = LandingController::new(config).unwrap();
        let platform = Vector2::new(2.0, 0.0);
        let mut velocity = Vector2::zeros();
        let mut desired = Vector2::zeros();
        for step in 1..=400 {
            let t_s = step as f64 * DT_S;
            let out = c
                .step(&LandingInput {
                    uav_velocity_ne_m_s: velocity,
                    platform_velocity_ne_m_s: platform,
                    ..input(t_s, fix_at(0.0, 0.0, 7.5), 7.5)
                })
                .unwrap();
            let command = out.velocity_setpoint_ned_m_s.xy();
            // Centred on the pad: the guidance wants the platform's velocity.
            desired = platform;
            let lag = DT_S / (config.autopilot_velocity_tau_s + DT_S);
            velocity += lag * (command - shortfall - velocity);
        }
        (velocity - desired).norm()
    };
    let without = fly(0.0);
    let with = fly(1.0);
    assert!(
        (without - shortfall.norm()).abs() < 0.05,
        "without: {without}"
    );
    assert!(with < 0.05, "with the feed-forward still {with} m/s off");
}

/// Descending at 0.7 m/s from 3 m above the ground with the wind pushing west at 4 m/s²:
/// the command moves west by what the log profile takes off the force 0.3 s lower, over
/// the velocity loop's gain (worked out here by hand); not while the vehicle only follows.
#[test]
fn the_wind_shear_feed_forward_leans_less_only_while_descending() {
    let config = LandingConfig {
        wind_shear_roughness_m: 0.05,
        ..LandingConfig::default()
    };
    let wind = NearGroundWind {
        altitude_m: 3.0,
        aerodynamic_accel_ne_m_s2: Vector2::new(0.0, -4.0),
    };
    let command = |descent_allowed: bool, wind: Option<NearGroundWind>| {
        let mut c = LandingController::new(config).unwrap();
        let mut t_s = 0.0;
        let mut out = None;
        for _ in 0..40 {
            t_s += DT_S;
            out = Some(
                c.step(&LandingInput {
                    descent_allowed,
                    near_ground_wind: wind,
                    ..input(t_s, fix_at(0.0, 0.0, 7.5), 7.5)
                })
                .unwrap(),
            );
        }
        out.unwrap()
    };
    let descending = command(true, Some(wind));
    assert_eq!(descending.mode, LandingMode::Descend);
    let plain = command(true, None);
    let ratio = ((2.79f64 / 0.05).ln() / (3.0f64 / 0.05).ln()).powi(2);
    let expected_east_m_s = -4.0 * (1.0 - ratio) * config.autopilot_velocity_tau_s;
    let shift = descending.velocity_setpoint_ned_m_s - plain.velocity_setpoint_ned_m_s;
    assert!(shift.x.abs() < 1e-12 && shift.z == 0.0, "{shift:?}");
    assert!((shift.y - expected_east_m_s).abs() < 1e-9, "{shift:?}");
    // Telemetry that gives no finite wind counts as none: no shift, no error.
    let garbled = NearGroundWind {
        altitude_m: f64::NAN,
        ..wind
    };
    assert_eq!(command(true, Some(garbled)), plain);
    let following = command(false, Some(wind));
    assert_eq!(following.mode, LandingMode::Follow);
    assert_eq!(following, command(false, None));
}

/// Committed 0.4 m over a pad 1 m above the ground at 2 m/s, the feed-forward's 0.6 m lead
/// would reach below the pad: the wind is predicted at the pad's surface, where the descent
/// ends (worked out by hand).
#[test]
fn the_wind_shear_is_never_predicted_below_the_pad() {
    // The height is set, not flown: no touchdown band from the descent's rate.
    let config = LandingConfig {
        wind_shear_roughness_m: 0.05,
        final_descent_speed_m_s: 2.0,
        touchdown_correction_lead_s: 0.0,
        ..LandingConfig::default()
    };
    let height_m = 0.4;
    let command = |wind: Option<NearGroundWind>| {
        let mut c = LandingController::new(config).unwrap();
        let mut t_s = 0.0;
        run(&mut c, &mut t_s, 1.0, Some(0.0), 7.5);
        assert_eq!(
            run(&mut c, &mut t_s, 1.0, Some(0.0), 1.5).mode,
            LandingMode::FinalLanding
        );
        t_s += DT_S;
        c.step(&LandingInput {
            near_ground_wind: wind,
            ..input(t_s, fix_at(0.0, 0.0, height_m), height_m)
        })
        .unwrap()
    };
    let wind = NearGroundWind {
        altitude_m: 1.0 + height_m,
        aerodynamic_accel_ne_m_s2: Vector2::new(0.0, -4.0),
    };
    let shift =
        command(Some(wind)).velocity_setpoint_ned_m_s - command(None).velocity_setpoint_ned_m_s;
    let ratio = ((1.0f64 / 0.05).ln() / (1.4f64 / 0.05).ln()).powi(2);
    let expected_east_m_s = -4.0 * (1.0 - ratio) * config.autopilot_velocity_tau_s;
    assert!(
        (shift.y - expected_east_m_s).abs() < 1e-9,
        "{shift:?} vs {expected_east_m_s}"
    );
}

/// Closed loop, east only: a velocity loop (proportional 1/τ, a slow integrator) holds the
/// vehicle over the pad against a west wind that weakens by the log profile as it comes
/// down onto a pad 1 m above the ground, with the reference mission's close-in gains. Its
/// integrator holds the lean of the wind aloft, so the vehicle drifts upwind on the way
/// down (7 cm); the feed-forward takes a third of that off.
#[test]
fn the_wind_shear_feed_forward_keeps_the_descent_over_the_pad() {
    let roughness_m = 0.05;
    let pad_altitude_m = 1.0;
    let wind_at = |altitude_m: f64| {
        -4.0 * ((altitude_m / roughness_m).ln() / (8.5f64 / roughness_m).ln()).powi(2)
    };
    let land = |wind_shear_roughness_m: f64| {
        let config = LandingConfig {
            wind_shear_roughness_m,
            ..close_in_config()
        };
        let gain_per_s = 1.0 / config.autopilot_velocity_tau_s;
        let mut c = LandingController::new(config).unwrap();
        let (mut east_m, mut velocity_m_s, mut height_m) = (0.0, 0.0, 7.5);
        // Settled at IH: the integrator holds the wind there.
        let mut integral_m_s2 = -wind_at(pad_altitude_m + height_m);
        let mut worst_m: f64 = 0.0;
        for step in 1..4000 {
            let t_s = step as f64 * 0.02;
            let aero = wind_at(pad_altitude_m + height_m);
            let out = c
                .step(&LandingInput {
                    platform_velocity_ne_m_s: Vector2::zeros(),
                    uav_velocity_ne_m_s: Vector2::new(0.0, velocity_m_s),
                    near_ground_wind: Some(NearGroundWind {
                        altitude_m: pad_altitude_m + height_m,
                        aerodynamic_accel_ne_m_s2: Vector2::new(0.0, aero),
                    }),
                    ..input(t_s, fix_at(0.0, east_m, height_m), height_m)
                })
                .unwrap();
            if out.mode == LandingMode::Landed {
                return (east_m.abs(), worst_m);
            }
            let error_m_s = out.velocity_setpoint_ned_m_s.y - velocity_m_s;
            integral_m_s2 += 0.4 * error_m_s * 0.02;
            velocity_m_s += (gain_per_s * error_m_s + integral_m_s2 + aero) * 0.02;
            east_m += velocity_m_s * 0.02;
            height_m = (height_m - out.velocity_setpoint_ned_m_s.z * 0.02).max(0.0);
            if height_m < 2.0 {
                worst_m = worst_m.max(east_m.abs());
            }
        }
        panic!("never landed");
    };
    let (without_m, worst_without_m) = land(0.0);
    let (with_m, worst_with_m) = land(roughness_m);
    assert!(
        without_m > 0.04,
        "the shear should push it off: {without_m} m"
    );
    assert!(
        with_m < 0.75 * without_m && worst_with_m < 0.75 * worst_without_m,
        "touchdown {with_m} m against {without_m} m, worst below 2 m {worst_with_m} against {worst_without_m} m"
    );
}

/// A gust that strikes after the commit, against a P+I velocity loop with a lagging
/// attitude: answered as it is felt, it pushes the vehicle off the pad by much less, and
/// before the commit (the same gust while following) the answer is not given.
#[test]
fn a_gust_after_the_commit_is_answered_as_it_is_felt() {
    let steady_m_s2 = -3.0;
    let gust_m_s2 = 2.5;
    let land = |gust_feed_forward_s: f64, gust_below_m: f64| {
        let config = LandingConfig {
            gust_feed_forward_s,
            ..close_in_config()
        };
        let mut c = LandingController::new(config).unwrap();
        let (mut east_m, mut velocity_m_s, mut height_m) = (0.0, 0.0, 7.5);
        // PX4's MPC_XY_VEL_P_ACC and _I_ACC, the attitude's 0.1 s lag; settled at IH.
        let (p_per_s, i_per_s2, attitude_tau_s) = (1.8, 0.4, 0.1);
        let mut integral_m_s2 = -steady_m_s2;
        let mut thrust_m_s2 = integral_m_s2;
        let mut shifts_before_commit_m_s: f64 = 0.0;
        for step in 1..4000 {
            let t_s = step as f64 * 0.02;
            let aero = if height_m < gust_below_m {
                steady_m_s2 + gust_m_s2
            } else {
                steady_m_s2
            };
            let out = c
                .step(&LandingInput {
                    platform_velocity_ne_m_s: Vector2::zeros(),
                    uav_velocity_ne_m_s: Vector2::new(0.0, velocity_m_s),
                    near_ground_wind: Some(NearGroundWind {
                        altitude_m: height_m,
                        aerodynamic_accel_ne_m_s2: Vector2::new(0.0, aero),
                    }),
                    ..input(t_s, fix_at(0.0, east_m, height_m), height_m)
                })
                .unwrap();
            if out.mode == LandingMode::Landed {
                return (east_m.abs(), shifts_before_commit_m_s);
            }
            if out.mode != LandingMode::FinalLanding {
                // With the vehicle over the pad and still, anything asked is an answer.
                shifts_before_commit_m_s = shifts_before_commit_m_s
                    .max((out.velocity_setpoint_ned_m_s.y - velocity_m_s).abs());
            }
            let error_m_s = out.velocity_setpoint_ned_m_s.y - velocity_m_s;
            integral_m_s2 += i_per_s2 * error_m_s * 0.02;
            let wanted_m_s2 = p_per_s * error_m_s + integral_m_s2;
            thrust_m_s2 += (wanted_m_s2 - thrust_m_s2) * 0.02 / attitude_tau_s;
            velocity_m_s += (thrust_m_s2 + aero) * 0.02;
            east_m += velocity_m_s * 0.02;
            height_m = (height_m - out.velocity_setpoint_ned_m_s.z * 0.02).max(0.0);
        }
        panic!("never landed");
    };
    // The gust strikes just below the commit height (1.5 m).
    let (without_m, _) = land(0.0, 1.2);
    let (with_m, _) = land(0.75, 1.2);
    assert!(
        without_m > 0.03,
        "the gust should push it off: {without_m} m"
    );
    assert!(
        with_m < 0.6 * without_m,
        "touchdown {with_m} m with the answer against {without_m} m without"
    );
    // Struck while following high above the pad, the vehicle is steered by the tracking
    // alone: the feed-forward asks for nothing beyond what the same flight without it asks.
    let (_, asked_with_m_s) = land(0.75, 5.0);
    let (_, asked_without_m_s) = land(0.0, 5.0);
    assert!(
        (asked_with_m_s - asked_without_m_s).abs() < 1e-12,
        "before the commit: {asked_with_m_s} against {asked_without_m_s} m/s"
    );
}

/// The same flight, with and without the gust's answer: after the commit a gust of
/// 2 m/s² east is answered by about its push × `gust_feed_forward_s` west (less what the
/// baseline has learned meanwhile); in the last centimetres not at all, so the commands
/// there are the same to the bit.
#[test]
fn the_gust_is_answered_after_the_commit_and_not_in_the_last_centimetres() {
    let controller = |gust_feed_forward_s: f64| {
        LandingController::new(LandingConfig {
            gust_feed_forward_s,
            ..LandingConfig::default()
        })
        .unwrap()
    };
    let (mut plain, mut answering) = (controller(0.0), controller(0.75));
    let mut t_s = 0.0;
    let mut both = |duration_s: f64, height_m: f64, aero_east_m_s2: f64| {
        let mut outputs = (None, None);
        for _ in 0..(duration_s / DT_S).round() as usize {
            t_s += DT_S;
            let step = LandingInput {
                near_ground_wind: Some(NearGroundWind {
                    altitude_m: height_m + 1.0,
                    aerodynamic_accel_ne_m_s2: Vector2::new(0.0, aero_east_m_s2),
                }),
                ..input(t_s, fix_at(0.0, 0.0, height_m), height_m)
            };
            outputs = (
                Some(plain.step(&step).unwrap()),
                Some(answering.step(&step).unwrap()),
            );
        }
        let (plain, answering) = (outputs.0.unwrap(), outputs.1.unwrap());
        assert_eq!(plain.mode, answering.mode);
        (plain, answering)
    };
    // Following and descending in a steady wind: no gust, nothing to answer.
    let (plain_out, answering_out) = both(1.0, 7.5, -3.0);
    assert_eq!(plain_out.mode, LandingMode::Descend);
    assert_eq!(plain_out, answering_out);
    let (plain_out, answering_out) = both(1.0, 1.4, -3.0);
    assert_eq!(plain_out.mode, LandingMode::FinalLanding);
    assert!(
        (plain_out.velocity_setpoint_ned_m_s - answering_out.velocity_setpoint_ned_m_s).norm()
            < 1e-9
    );
    // The gust, 0.3 s long: felt through the 0.2 s filter, less the 1 s baseline's share.
    let (plain_out, answering_out) = both(0.3, 0.8, -1.0);
    let answer_east_m_s =
        answering_out.velocity_setpoint_ned_m_s.y - plain_out.velocity_setpoint_ned_m_s.y;
    let felt = 1.0 - (0.2f64 / (0.2 + DT_S)).powi(6);
    let learned = 1.0 - (1.0f64 / (1.0 + DT_S)).powi(6);
    let expected_m_s = -2.0 * (felt - learned) * 0.75;
    assert!(
        (answer_east_m_s - expected_m_s).abs() < 1e-9 && expected_m_s < -0.5,
        "answered {answer_east_m_s} m/s, expected {expected_m_s}"
    );
    // In the last centimetres the gust goes unanswered.
    let (plain_out, answering_out) = both(DT_S, 0.2, -1.0);
    assert_eq!(plain_out.mode, LandingMode::FinalLanding);
    assert_eq!(plain_out, answering_out);
}

/// A vehicle held still by its autopilot (a failsafe, a pilot) while the guidance asks for
/// 2 m/s: told its setpoints are not flown, the controller learns no wind, and once they
/// are flown again it asks for what it would ask of a vehicle that had never been held.
#[test]
fn no_wind_is_learned_while_the_setpoints_are_not_flown() {
    let config = LandingConfig {
        wind_compensation_tau_s: 1.0,
        ..LandingConfig::default()
    };
    let platform = Vector2::new(2.0, 0.0);
    let step = |c: &mut LandingController, t_s: f64, followed: bool| {
        c.step(&LandingInput {
            uav_velocity_ne_m_s: Vector2::zeros(),
            platform_velocity_ne_m_s: platform,
            setpoints_followed: followed,
            pad_in_view_offset_per_height: Vector2::zeros(),
            ..input(t_s, fix_at(0.0, 0.0, 7.5), 7.5)
        })
        .unwrap()
        .velocity_setpoint_ned_m_s
        .xy()
    };
    let mut held = LandingController::new(config).unwrap();
    for k in 1..=200 {
        step(&mut held, k as f64 * DT_S, false);
    }
    let after_hold = step(&mut held, 201.0 * DT_S, true);
    let mut fresh = LandingController::new(config).unwrap();
    let first = step(&mut fresh, 201.0 * DT_S, true);
    // (One step of learning apart: the first step flown after the hold.)
    assert!(
        (after_hold - first).norm() < 0.05,
        "{after_hold} after the hold, {first} fresh"
    );
    // Whereas a vehicle that does not move although it flies the setpoints is short of
    // them: that is learned as wind.
    let mut short = LandingController::new(config).unwrap();
    for k in 1..=200 {
        step(&mut short, k as f64 * DT_S, true);
    }
    let compensated = step(&mut short, 201.0 * DT_S, true);
    assert!(
        (compensated - first).norm() > 1.0,
        "{compensated} vs {first}"
    );
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
