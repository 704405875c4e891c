use super::*;
use nalgebra::UnitQuaternion;

fn at_rest(yaw_rad: f64, down_m: f64) -> BodyState {
    BodyState {
        position_ned_m: Vector3::new(0.0, 0.0, down_m),
        velocity_ned_m_s: Vector3::zeros(),
        acceleration_ned_m_s2: Vector3::zeros(),
        attitude: UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_rad),
        body_rates_rad_s: Vector3::zeros(),
    }
}

#[test]
fn the_standard_atmosphere_matches_its_table() {
    // ICAO standard atmosphere table: 0 m 1013.25 hPa 15 °C; 500 m 954.61 hPa 11.75 °C;
    // 1000 m 898.76 hPa 8.5 °C.
    for (altitude, hpa, celsius) in [
        (0.0, 1013.25, 15.0),
        (500.0, 954.61, 11.75),
        (1000.0, 898.76, 8.5),
    ] {
        let (p, t) = standard_atmosphere(altitude);
        assert!((p - hpa).abs() < 0.02, "{altitude} m: {p} hPa");
        assert!((t - celsius).abs() < 1e-9, "{altitude} m: {t} °C");
        assert!((pressure_altitude_m(p) - altitude).abs() < 1e-6);
    }
}

#[test]
fn local_positions_become_geodetic_ones_a_distance_apart() {
    let home = Home::default();
    let (lat, lon, alt) = home.geodetic(&Vector3::new(300.0, -400.0, -20.0));
    // Independent: the haversine distance on a sphere of the WGS-84 equatorial radius.
    let (p1, p2) = (home.latitude_deg.to_radians(), lat.to_radians());
    let dl = (lon - home.longitude_deg).to_radians();
    let a = ((p2 - p1) / 2.0).sin().powi(2) + p1.cos() * p2.cos() * (dl / 2.0).sin().powi(2);
    let distance = 2.0 * 6_378_137.0 * a.sqrt().asin();
    assert!((distance - 500.0).abs() < 0.05, "{distance}");
    assert!(lat > home.latitude_deg && lon < home.longitude_deg);
    assert!((alt - 508.0).abs() < 1e-9);
}

#[test]
fn the_imu_at_rest_reads_gravity_with_the_noise_it_is_given() {
    let params = SensorParams::default();
    let mut sensors = Sensors::new(params, Home::default(), 7);
    let dt = 0.004;
    let n = 5_000;
    let samples: Vec<ImuSample> = (0..n)
        .map(|_| sensors.imu(dt, &at_rest(0.0, 0.0)))
        .collect();
    let mean = |f: &dyn Fn(&ImuSample) -> f64| samples.iter().map(f).sum::<f64>() / n as f64;
    let std = |f: &dyn Fn(&ImuSample) -> f64| {
        let m = mean(f);
        (samples.iter().map(|s| (f(s) - m).powi(2)).sum::<f64>() / n as f64).sqrt()
    };
    let z = mean(&|s| s.accel_frd_m_s2.z);
    assert!((z + 9.80665).abs() < 0.1, "{z}");
    // White noise: density × √(250 Hz); the bias wanders far slower than 20 s.
    let expected = 0.004 * 250f64.sqrt();
    let measured = std(&|s| s.accel_frd_m_s2.x);
    assert!(
        (measured / expected - 1.0).abs() < 0.1,
        "{measured} vs {expected}"
    );
    let expected = 0.000_339_4 * 250f64.sqrt();
    let measured = std(&|s| s.gyro_frd_rad_s.y);
    assert!(
        (measured / expected - 1.0).abs() < 0.1,
        "{measured} vs {expected}"
    );
    // The barometer at home's altitude: about 955.5 hPa at 488 m.
    let altitude = mean(&|s| s.pressure_altitude_m);
    assert!((altitude - 488.0).abs() < 1.0, "{altitude}");
}

#[test]
fn the_magnetometer_sees_home_field_turn_with_the_body() {
    let params = SensorParams {
        mag_noise_gauss: 0.0,
        ..SensorParams::default()
    };
    let field = params.earth_field_ned_gauss;
    // The field itself: 0.484 G, inclination 63.6°, declination 3.2°.
    assert!((field.norm() - 0.484).abs() < 1e-9);
    let inclination = field.z.atan2(field.xy().norm()).to_degrees();
    assert!((inclination - 63.6).abs() < 1e-9);
    let mut sensors = Sensors::new(params, Home::default(), 1);
    let north = sensors.imu(0.004, &at_rest(0.0, 0.0)).mag_frd_gauss;
    assert!((north - field).norm() < 1e-12);
    // Facing east, the body's x axis sees the east component and its y axis (south) minus
    // the north one.
    let east = sensors
        .imu(0.004, &at_rest(std::f64::consts::FRAC_PI_2, 0.0))
        .mag_frd_gauss;
    assert!((east.x - field.y).abs() < 1e-12 && (east.y + field.x).abs() < 1e-12);
    assert!((east.z - field.z).abs() < 1e-12);
}

#[test]
fn gps_fixes_come_at_ten_hertz_with_a_slow_drift() {
    let mut sensors = Sensors::new(SensorParams::default(), Home::default(), 3);
    let body = at_rest(0.0, -10.0);
    let mut fixes = Vec::new();
    for i in 0..2_500 {
        if let Some(fix) = sensors.gps(i as f64 * 0.004, &body) {
            fixes.push(fix);
        }
    }
    assert_eq!(fixes.len(), 100, "10 s at 10 Hz");
    // Consecutive fixes differ by the white noise, not by the drift (σ 0.4 m).
    let home = Home::default();
    let north = |f: &GpsFix| (f.latitude_deg - home.latitude_deg).to_radians() * 6_378_137.0;
    let steps: Vec<f64> = fixes
        .windows(2)
        .map(|w| north(&w[1]) - north(&w[0]))
        .collect();
    let step_rms = (steps.iter().map(|s| s * s).sum::<f64>() / steps.len() as f64).sqrt();
    assert!(step_rms < 0.15, "{step_rms}");
    assert!(fixes.iter().all(|f| (f.altitude_m - 498.0).abs() < 5.0));
    assert!(fixes.iter().all(|f| f.horizontal_accuracy_m > 0.3));
}

#[test]
fn the_same_seed_gives_the_same_sensors() {
    let run = |seed| {
        let mut sensors = Sensors::new(SensorParams::default(), Home::default(), seed);
        (0..100)
            .map(|_| sensors.imu(0.004, &at_rest(0.3, -5.0)).accel_frd_m_s2)
            .collect::<Vec<_>>()
    };
    assert_eq!(run(5), run(5));
    assert_ne!(run(5), run(6));
}
