//! The served world's pure parts: vehicle specs and the touchdown judge.

use super::served::judge;
use super::*;
use nalgebra::{Vector2, Vector3};
use sim::camera::VehiclePose;
use sim::tractor::PadState;
use sim::vehicle::Touchdown;

#[test]
fn vehicles_parse() {
    assert_eq!("sim".parse(), Ok(ServeVehicle::Simulated));
    assert_eq!("px4-sih".parse(), Ok(ServeVehicle::Px4Sih { instance: 0 }));
    assert_eq!(
        "px4-sih:3".parse(),
        Ok(ServeVehicle::Px4Sih { instance: 3 })
    );
    assert_eq!("px4-hil".parse(), Ok(ServeVehicle::Px4Hil { instance: 0 }));
    assert_eq!(
        "px4-hil:7".parse(),
        Ok(ServeVehicle::Px4Hil { instance: 7 })
    );
    assert_eq!(
        "ardupilot-json".parse(),
        Ok(ServeVehicle::ArduPilotJson { instance: 0 })
    );
    assert_eq!(
        "ardupilot-json:2".parse(),
        Ok(ServeVehicle::ArduPilotJson { instance: 2 })
    );
    for bad in [
        "px4",
        "px4-sih:10",
        "px4-sih:x",
        "gazebo:1",
        "sim:1",
        "ardupilot",
    ] {
        let error = bad.parse::<ServeVehicle>().unwrap_err();
        assert!(
            error.contains("px4-sih") || error.contains("0-9"),
            "{error}"
        );
    }
    for (bad, wanted) in [
        ("px4-hil:10", "px4-hil:10: the instance is 0-9"),
        ("ardupilot-json:x", "ardupilot-json:x: the instance is 0-9"),
    ] {
        assert_eq!(bad.parse::<ServeVehicle>().unwrap_err(), wanted);
    }
}

#[test]
fn only_the_hil_vehicles_are_real_autopilots_the_user_started() {
    let timeout = Duration::from_secs(7);
    for vehicle in [
        ServeVehicle::Simulated,
        ServeVehicle::Px4Sih { instance: 1 },
    ] {
        assert_eq!(vehicle.real_autopilot(timeout), None);
    }
    let px4 = ServeVehicle::Px4Hil { instance: 3 }
        .real_autopilot(timeout)
        .unwrap();
    assert_eq!(
        px4,
        RealAutopilot {
            kind: AutopilotKind::Px4,
            instance: 3,
            command: None,
            connect_timeout: timeout,
        }
    );
    let ardupilot = ServeVehicle::ArduPilotJson { instance: 2 }
        .real_autopilot(timeout)
        .unwrap();
    assert_eq!(ardupilot.kind, AutopilotKind::ArduPilot);
    // The runtime's MAVLink goes to the autopilot itself.
    assert_eq!(ardupilot.mavlink_address(), "tcpout:127.0.0.1:5780");
    assert_eq!(
        ServeVehicle::ArduPilotJson { instance: 2 }.describe(),
        "ArduPilot SITL JSON instance 2"
    );
}

#[test]
fn a_real_touchdown_is_served_as_the_body_felt_it() {
    let touchdown = Touchdown {
        time_s: 41.3,
        on_pad: true,
        offset_in_pad_frame_m: Vector2::new(0.03, -0.04),
        horizontal_error_m: 0.05,
        vertical_speed_m_s: 0.6,
        relative_horizontal_speed_m_s: 0.2,
        tilt_deg: 3.5,
    };
    assert_eq!(
        ServedTouchdown::from(touchdown),
        ServedTouchdown {
            time_s: 41.3,
            on_pad: true,
            horizontal_error_m: 0.05,
            vertical_speed_m_s: 0.6,
            tilt_deg: 3.5,
        }
    );
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
