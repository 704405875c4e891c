//! The wind near the ground, as a descending multirotor meets it.
//!
//! Over a field the mean wind follows the logarithmic profile W(h) = W_ref·ln(h/z0)/ln(h_ref/z0)
//! (MIL-F-8785C's low-altitude mean wind; z0 ≈ 0.05 m over crops, ESDU 82026), so a vehicle
//! dropping its last metres onto a tractor meets a wind that weakens by a third or more. The
//! autopilot's velocity loop holds the lean the stronger wind needed and its integrator lets go
//! of it only slowly: the vehicle drifts upwind in the last second. Knowing the wind's force now
//! (from the lean) and the profile, the force at the height the vehicle will reach is predicted,
//! and the velocity command is shifted downwind by what the velocity loop will otherwise fall
//! short.

use nalgebra::{Rotation3, Vector2, Vector3};

/// Standard gravity.
const GRAVITY_M_S2: f64 = 9.80665;

/// The horizontal aerodynamic acceleration on a multirotor (wind and drag together), NE: what
/// it measures (`acceleration_ned_m_s2`) less what its thrust gives, the thrust along the
/// body's −z and as large as holds the measured vertical acceleration (no vertical aerodynamic
/// force). None while the body points sideways or upside down.
pub fn aerodynamic_accel_ne_m_s2(
    body_to_ned: &Rotation3<f64>,
    acceleration_ned_m_s2: &Vector3<f64>,
) -> Option<Vector2<f64>> {
    let body_down_ned = body_to_ned * Vector3::z();
    // The thrust's share that holds the vehicle up; below ~60° of tilt only.
    if body_down_ned.z < 0.5 {
        return None;
    }
    let thrust_per_mass_m_s2 = (GRAVITY_M_S2 - acceleration_ned_m_s2.z) / body_down_ned.z;
    let thrust_ne = -body_down_ned.xy() * thrust_per_mass_m_s2;
    Some(acceleration_ned_m_s2.xy() - thrust_ne)
}

/// The ratio of the wind's force at `to_altitude_m` to that at `from_altitude_m` under the
/// logarithmic profile with roughness length `roughness_m` (force ∝ speed²). Heights below
/// twice the roughness length count as that: the profile is not meant for the crops' canopy.
pub fn log_profile_force_ratio(from_altitude_m: f64, to_altitude_m: f64, roughness_m: f64) -> f64 {
    let floor_m = 2.0 * roughness_m;
    let speed = |altitude_m: f64| (altitude_m.max(floor_m) / roughness_m).ln();
    (speed(to_altitude_m) / speed(from_altitude_m)).powi(2)
}

/// The velocity command's shift (NE) that makes up, ahead of time, the velocity loop's shortfall
/// as the aerodynamic force `aero_accel_ne_m_s2` measured at `altitude_m` changes to what the
/// profile gives `lead_m` lower. A velocity loop of proportional gain 1/`velocity_tau_s` falls
/// short by the change of force over its gain; the shift is that shortfall, the other way.
pub fn descent_feed_forward_ne_m_s(
    aero_accel_ne_m_s2: Vector2<f64>,
    altitude_m: f64,
    lead_m: f64,
    roughness_m: f64,
    velocity_tau_s: f64,
) -> Vector2<f64> {
    let ratio = log_profile_force_ratio(altitude_m, altitude_m - lead_m, roughness_m);
    let change_m_s2 = aero_accel_ne_m_s2 * (ratio - 1.0);
    // Less wind ahead: less lean is needed, so ask for a velocity downwind of the one wanted.
    -change_m_s2 * velocity_tau_s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_vehicle_leaning_still_into_the_wind_feels_the_wind_push_back() {
        // Pitched 20° nose down facing north (thrust tilted north), not accelerating: the
        // wind pushes south by g·tan 20°, computed here from the geometry by hand.
        let pitch = -20f64.to_radians();
        let body_to_ned = Rotation3::from_euler_angles(0.0, pitch, 0.0);
        let aero = aerodynamic_accel_ne_m_s2(&body_to_ned, &Vector3::zeros()).unwrap();
        assert!((aero.x + GRAVITY_M_S2 * 20f64.to_radians().tan()).abs() < 1e-9);
        assert!(aero.y.abs() < 1e-12);
        // Level and accelerating east at 2 m/s²: something other than thrust pushes it.
        let level = Rotation3::identity();
        let aero = aerodynamic_accel_ne_m_s2(&level, &Vector3::new(0.0, 2.0, 0.0)).unwrap();
        assert_eq!(aero, Vector2::new(0.0, 2.0));
        // On its side: no estimate.
        let side = Rotation3::from_euler_angles(80f64.to_radians(), 0.0, 0.0);
        assert!(aerodynamic_accel_ne_m_s2(&side, &Vector3::zeros()).is_none());
    }

    #[test]
    fn the_force_ratio_is_the_squared_ratio_of_logarithms() {
        let z0 = 0.05;
        let expected = ((1.0f64 / z0).ln() / (3.0f64 / z0).ln()).powi(2);
        assert!((log_profile_force_ratio(3.0, 1.0, z0) - expected).abs() < 1e-12);
        assert!((log_profile_force_ratio(2.0, 2.0, z0) - 1.0).abs() < 1e-12);
        // Below the floor the force stops falling.
        let at_floor = log_profile_force_ratio(3.0, 2.0 * z0, z0);
        assert_eq!(log_profile_force_ratio(3.0, 0.0, z0), at_floor);
        assert!(at_floor > 0.0 && at_floor < expected);
    }

    #[test]
    fn descending_into_weaker_wind_shifts_the_command_downwind() {
        // Wind pushing west at 4 m/s² at 2.5 m; 0.75 m lower it is weaker, so the vehicle
        // must lean less: the command moves west by the change over the loop's gain.
        let aero = Vector2::new(0.0, -4.0);
        let shift = descent_feed_forward_ne_m_s(aero, 2.5, 0.75, 0.05, 0.5);
        let ratio = log_profile_force_ratio(2.5, 1.75, 0.05);
        assert!(shift.y < 0.0 && shift.x == 0.0);
        assert!((shift.y - (-4.0 * (1.0 - ratio) * 0.5)).abs() < 1e-12);
        // No descent, no shift.
        assert_eq!(
            descent_feed_forward_ne_m_s(aero, 2.5, 0.0, 0.05, 0.5),
            Vector2::zeros()
        );
    }
}
