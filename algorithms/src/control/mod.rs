//! Guidance and control: the two-stage PID of seed 000 §2.3, the landing state machine of
//! seed 000 §3, and a point-mass vehicle for closed-loop tests and the simulator.

pub mod landing;
pub mod mpc;
pub mod pid;
pub mod point_mass;
pub mod wind_shear;

#[cfg(test)]
pub(crate) mod closed_loop_tests {
    //! The PID and the landing state machine flying the point mass onto a platform that moves
    //! at 3 m/s and makes a 180° turn.

    use super::landing::{
        HorizontalController, LandingConfig, LandingController, LandingInput, RelativeFix,
    };
    use super::mpc::MpcConfig;
    use super::point_mass::{PointMass, PointMassConfig};
    use nalgebra::{Vector2, Vector3};
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};
    use std::f64::consts::PI;

    const PLATFORM_SPEED_M_S: f64 = 3.0;
    const TURN_RADIUS_M: f64 = 6.0;

    /// Pad position and velocity (NE): north at 3 m/s, from `turn_start_s` a half circle of
    /// radius 6 m to the east, then south at 3 m/s.
    pub(crate) fn platform(t_s: f64, turn_start_s: f64) -> (Vector2<f64>, Vector2<f64>) {
        let v = PLATFORM_SPEED_M_S;
        let turn_duration_s = PI * TURN_RADIUS_M / v;
        if t_s <= turn_start_s {
            return (Vector2::new(v * t_s, 0.0), Vector2::new(v, 0.0));
        }
        let entry_n_m = v * turn_start_s;
        let centre = Vector2::new(entry_n_m, TURN_RADIUS_M);
        let along_s = (t_s - turn_start_s).min(turn_duration_s);
        // The turn's centre is 6 m east of the entry point; the angle swept so far runs
        // from 0 to π.
        let angle_rad = PI * along_s / turn_duration_s;
        let on_circle = centre + TURN_RADIUS_M * Vector2::new(angle_rad.sin(), -angle_rad.cos());
        let tangent = v * Vector2::new(angle_rad.cos(), angle_rad.sin());
        if t_s - turn_start_s <= turn_duration_s {
            (on_circle, tangent)
        } else {
            let after_s = t_s - turn_start_s - turn_duration_s;
            (
                on_circle + Vector2::new(-v * after_s, 0.0),
                Vector2::new(-v, 0.0),
            )
        }
    }

    struct Outcome {
        touchdown_error_m: f64,
        touchdown_time_s: f64,
        committed_at_s: f64,
        max_speed_m_s: f64,
    }

    fn fly(config: LandingConfig, turn_start_s: f64, noise_std_m: f64, seed: u64) -> Outcome {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut gaussian = move || {
            // Box–Muller; rand_distr is not a dependency.
            let u1: f64 = 1.0 - rng.random::<f64>();
            let u2: f64 = rng.random::<f64>();
            (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
        };
        let mut controller = LandingController::new(config).unwrap();
        let mut vehicle =
            PointMass::new(PointMassConfig::default(), Vector3::new(-4.0, 3.0, -5.0)).unwrap();
        let physics_dt_s = 0.005;
        let control_every = 10; // 20 Hz control loop
        let mut setpoint = Vector3::zeros();
        let mut committed_at_s = f64::NAN;
        let mut max_speed_m_s: f64 = 0.0;
        for k in 0..(120.0 / physics_dt_s) as usize {
            let t_s = k as f64 * physics_dt_s;
            let (pad_ne_m, pad_velocity_ne_m_s) = platform(t_s, turn_start_s);
            let height_m = -vehicle.position_ned_m.z;
            let error_ne = vehicle.position_ned_m.xy() - pad_ne_m;
            if height_m <= 0.0 {
                return Outcome {
                    touchdown_error_m: error_ne.norm(),
                    touchdown_time_s: t_s,
                    committed_at_s,
                    max_speed_m_s,
                };
            }
            if k % control_every == 0 {
                // The target comes into view after 1 s.
                let fix = (t_s >= 1.0).then(|| {
                    let noise = Vector3::new(gaussian(), gaussian(), gaussian()) * noise_std_m;
                    RelativeFix::with_std(
                        Vector3::new(error_ne.x, error_ne.y, -height_m) + noise,
                        noise_std_m.max(0.01),
                    )
                });
                let out = controller
                    .step(&LandingInput {
                        time_s: t_s,
                        fix,
                        height_above_pad_m: height_m,
                        platform_velocity_ne_m_s: pad_velocity_ne_m_s,
                        touchdown_detected: false,
                        uav_velocity_ne_m_s: vehicle.velocity_ned_m_s.xy(),
                        descent_allowed: true,
                        predicted_uav_minus_pad_ne_m: None,
                        setpoints_followed: true,
                        pad_in_view_offset_per_height: Vector2::zeros(),
                        near_ground_wind: None,
                    })
                    .unwrap();
                if out.land_command && committed_at_s.is_nan() {
                    committed_at_s = t_s;
                }
                setpoint = out.velocity_setpoint_ned_m_s;
            }
            vehicle.step(setpoint, physics_dt_s).unwrap();
            max_speed_m_s = max_speed_m_s.max(vehicle.velocity_ned_m_s.xy().norm());
        }
        panic!("no touchdown within 120 s (mode {:?})", controller.mode());
    }

    /// Turn start times every 0.5 s from 0 to 18 s: the landing takes about 17 s, so the turn
    /// (6.3 s long) overlaps every phase: following, descent, the commit and the final landing.
    fn sweep(config: LandingConfig) -> (f64, usize) {
        let mut worst_m: f64 = 0.0;
        let mut runs = 0;
        for half_seconds in 0..=36 {
            let turn_start_s = half_seconds as f64 * 0.5;
            for (noise_std_m, seed) in [(0.0, 0), (0.03, half_seconds), (0.03, 100 + half_seconds)]
            {
                let o = fly(config, turn_start_s, noise_std_m, seed);
                assert!(o.committed_at_s.is_finite(), "never committed");
                assert!(o.committed_at_s < o.touchdown_time_s);
                worst_m = worst_m.max(o.touchdown_error_m);
                runs += 1;
                if (half_seconds % 6 == 0 && seed < 100) || o.touchdown_error_m > 0.1 {
                    println!(
                        "lead {:.1} s, turn at {turn_start_s:>4.1} s, noise {noise_std_m:.2} m: \
                         commit {:.2} s, touchdown {:.2} s, error {:.3} m, max speed {:.2} m/s",
                        config.platform_accel_lead_s,
                        o.committed_at_s,
                        o.touchdown_time_s,
                        o.touchdown_error_m,
                        o.max_speed_m_s
                    );
                }
            }
        }
        (worst_m, runs)
    }

    #[test]
    fn touchdown_within_15_cm_on_a_turning_platform() {
        let (worst_m, runs) = sweep(LandingConfig::default());
        println!("default config: worst touchdown error {worst_m:.3} m over {runs} runs");
        assert!(worst_m <= 0.15, "worst touchdown error {worst_m:.3} m");
    }

    /// The same sweep with the MPC selected in place of the PID, its model step equal to the
    /// 20 Hz control period: the state machine with either controller lands within 15 cm.
    #[test]
    fn mpc_selected_touchdown_within_15_cm_on_a_turning_platform() {
        let config = LandingConfig {
            controller: HorizontalController::Mpc(MpcConfig {
                dt_s: 0.05,
                // Generous for a loaded CI machine; a late solve flies the fallback anyway.
                solve_time_limit_s: 0.05,
                ..MpcConfig::default()
            }),
            // The MPC extrapolates the acceleration over its horizon, so it wants it fresher
            // than the PID's lead term does.
            platform_accel_filter_tau_s: 0.1,
            ..LandingConfig::default()
        };
        let (worst_m, runs) = sweep(config);
        println!("MPC: worst touchdown error {worst_m:.3} m over {runs} runs");
        assert!(worst_m <= 0.15, "worst touchdown error {worst_m:.3} m");
    }

    /// The seed's law alone (no acceleration feed-forward): on a straight line it lands on
    /// centre; in the turn the velocity loop's lag leaves an offset of about a·τ/kp
    /// (1.5 m/s² · 0.2 s / 1.5 per s = 0.2 m), which the figures printed here show.
    #[test]
    fn seed_law_without_acceleration_feed_forward() {
        let config = LandingConfig {
            platform_accel_lead_s: 0.0,
            ..LandingConfig::default()
        };
        for seed in 0..5 {
            let o = fly(config, 1e6, 0.03, seed);
            assert!(
                o.touchdown_error_m <= 0.05,
                "straight line: {:.3} m",
                o.touchdown_error_m
            );
        }
        let (worst_m, runs) = sweep(config);
        println!("seed law, lead 0: worst touchdown error {worst_m:.3} m over {runs} runs");
        assert!(worst_m < 0.5);
    }
}
