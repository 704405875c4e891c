//! The served world's pure parts: vehicle specs and the touchdown judge.

use super::*;

#[test]
fn vehicles_parse() {
    assert_eq!("sim".parse(), Ok(ServeVehicle::Simulated));
    assert_eq!("px4-sih".parse(), Ok(ServeVehicle::Px4Sih { instance: 0 }));
    assert_eq!(
        "px4-sih:3".parse(),
        Ok(ServeVehicle::Px4Sih { instance: 3 })
    );
    for bad in ["px4", "px4-sih:10", "px4-sih:x", "gazebo:1"] {
        let error = bad.parse::<ServeVehicle>().unwrap_err();
        assert!(
            error.contains("px4-sih") || error.contains("0-9"),
            "{error}"
        );
    }
}

#[test]
fn a_touchdown_is_judged_against_the_pad_in_its_own_frame() {
    // A pad heading east at (10, 5); the vehicle 0.3 m ahead of it, 0.2 m to its right.
    let pad = PadState {
        centre_ned_m: Vector3::new(10.0, 5.0, 0.0),
        yaw_rad: std::f64::consts::FRAC_PI_2,
        velocity_ned_m_s: Vector3::new(0.0, 1.0, 0.0),
        half_size_m: 0.5,
    };
    let pose = |north_m: f64, east_m: f64| VehiclePose {
        position_ned_m: Vector3::new(north_m, east_m, -0.1),
        attitude: Default::default(),
        velocity_ned_m_s: Vector3::new(0.0, 1.0, 0.4),
        body_rates_rad_s: Vector3::zeros(),
    };
    let on = judge(3.0, &pose(10.0 - 0.2, 5.3), &pad);
    assert!(on.on_pad);
    assert!((on.horizontal_error_m - 0.13f64.sqrt()).abs() < 1e-9);
    let off = judge(3.0, &pose(10.0, 5.6), &pad);
    assert!(!off.on_pad);
    assert!((off.horizontal_error_m - 0.6).abs() < 1e-9);
}
