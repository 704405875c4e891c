//! The wind: the autopilot's shortfall fed forward, the wind shear near the ground, a gust
//! after the commit, and no wind learned while the setpoints are not flown.

use super::*;

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
