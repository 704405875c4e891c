//! A real drone's sensors sampled from the world's true state, for an autopilot whose
//! estimator runs on them (PX4's EKF2 over HIL, ArduPilot's EKF3 over JSON): IMU with noise
//! and slowly wandering bias, a magnetometer in the home location's field, a barometer with
//! drift, GPS at 10 Hz with noise and slow drift, the downward rangefinder. Each effect is a
//! parameter; its default names where the figure comes from. Deterministic per seed.

use algorithms::vision::render::SplitMix64;
use nalgebra::Vector3;

use crate::quadrotor::BodyState;
use crate::realism::GaussMarkov;

/// WGS-84 equatorial radius: the local tangent plane around home.
const EARTH_RADIUS_M: f64 = 6_378_137.0;

/// Where the world's origin (NED 0, 0, 0: the take-off point on the ground) is on the Earth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Home {
    pub latitude_deg: f64,
    pub longitude_deg: f64,
    /// Above mean sea level.
    pub altitude_m: f64,
}

impl Default for Home {
    /// PX4 SITL's default home (Zurich, the PX4_HOME_* defaults), which ArduPilot's SITL is
    /// told too.
    fn default() -> Self {
        Self {
            latitude_deg: 47.397742,
            longitude_deg: 8.545594,
            altitude_m: 488.0,
        }
    }
}

impl Home {
    /// Latitude and longitude (degrees) and altitude AMSL of a local NED position (flat Earth
    /// around home: centimetre-exact over the few hundred metres a mission flies).
    pub fn geodetic(&self, position_ned_m: &Vector3<f64>) -> (f64, f64, f64) {
        let lat0 = self.latitude_deg.to_radians();
        let latitude = self.latitude_deg + (position_ned_m.x / EARTH_RADIUS_M).to_degrees();
        let longitude =
            self.longitude_deg + (position_ned_m.y / (EARTH_RADIUS_M * lat0.cos())).to_degrees();
        (latitude, longitude, self.altitude_m - position_ned_m.z)
    }
}

/// The sensors' imperfections.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorParams {
    /// Accelerometer white noise density, m/s²/√Hz (ADIS16448, the IMU Gazebo Classic's PX4
    /// models carry: 0.004; at 250 Hz 0.063 m/s² per sample).
    pub accel_noise_density: f64,
    /// Accelerometer bias: its turn-on spread and wander (Gauss–Markov), m/s² and s (Gazebo
    /// Classic's IMU plugin: turn-on 0.196 is what EKF2 has to learn; wander τ = 300 s; we use
    /// a tenth of the turn-on so PX4's preflight bias check passes as on a calibrated drone).
    pub accel_bias_m_s2: f64,
    pub accel_bias_tau_s: f64,
    /// Gyroscope white noise density, rad/s/√Hz (ADIS16448: 0.0003394).
    pub gyro_noise_density: f64,
    /// Gyroscope bias spread and wander, rad/s and s (Gazebo Classic: 0.0087 turn-on, τ 1000 s;
    /// a calibrated drone's residual: a tenth).
    pub gyro_bias_rad_s: f64,
    pub gyro_bias_tau_s: f64,
    /// The Earth's field at home, NED, gauss (NOAA WMM2025 at 47.398 N 8.546 E: 48.4 µT,
    /// inclination 63.6°, declination 3.2° E).
    pub earth_field_ned_gauss: Vector3<f64>,
    /// Magnetometer white noise per sample, gauss (HMC5883-class: about 1 mG).
    pub mag_noise_gauss: f64,
    /// Barometer white noise, hPa (MS5611: 0.012 hPa RMS at its highest resolution), and its
    /// slow drift as an altitude (Gauss–Markov), m and s.
    pub baro_noise_hpa: f64,
    pub baro_drift_m: f64,
    pub baro_drift_tau_s: f64,
    /// GPS rate (a u-blox M8 at 10 Hz).
    pub gps_rate_hz: f64,
    /// GPS position white noise and slow drift (Gauss–Markov; u-blox M8 open-sky CEP 2.5 m is
    /// mostly this drift), horizontal and vertical, m, and the drift's correlation time.
    pub gps_noise_horizontal_m: f64,
    pub gps_noise_vertical_m: f64,
    pub gps_drift_horizontal_m: f64,
    pub gps_drift_vertical_m: f64,
    pub gps_drift_tau_s: f64,
    /// GPS velocity white noise, m/s (u-blox M8: 0.05 m/s).
    pub gps_velocity_noise_m_s: f64,
    /// Rangefinder white noise, m (a LiDAR-Lite v3: 2.5 cm).
    pub rangefinder_noise_m: f64,
}

impl Default for SensorParams {
    fn default() -> Self {
        let (inclination, declination) = (63.6f64.to_radians(), 3.2f64.to_radians());
        let total_gauss = 0.484;
        let horizontal = total_gauss * inclination.cos();
        Self {
            accel_noise_density: 0.004,
            accel_bias_m_s2: 0.02,
            accel_bias_tau_s: 300.0,
            gyro_noise_density: 0.000_339_4,
            gyro_bias_rad_s: 0.000_87,
            gyro_bias_tau_s: 1000.0,
            earth_field_ned_gauss: Vector3::new(
                horizontal * declination.cos(),
                horizontal * declination.sin(),
                total_gauss * inclination.sin(),
            ),
            mag_noise_gauss: 0.001,
            baro_noise_hpa: 0.012,
            baro_drift_m: 0.2,
            baro_drift_tau_s: 120.0,
            gps_rate_hz: 10.0,
            gps_noise_horizontal_m: 0.05,
            gps_noise_vertical_m: 0.1,
            gps_drift_horizontal_m: 0.4,
            gps_drift_vertical_m: 0.8,
            gps_drift_tau_s: 60.0,
            gps_velocity_noise_m_s: 0.05,
            rangefinder_noise_m: 0.025,
        }
    }
}

/// One IMU, magnetometer and barometer sample (PX4's HIL_SENSOR).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    pub accel_frd_m_s2: Vector3<f64>,
    pub gyro_frd_rad_s: Vector3<f64>,
    pub mag_frd_gauss: Vector3<f64>,
    pub pressure_hpa: f64,
    pub pressure_altitude_m: f64,
    pub temperature_c: f64,
}

/// One GPS fix (PX4's HIL_GPS).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GpsFix {
    pub latitude_deg: f64,
    pub longitude_deg: f64,
    pub altitude_m: f64,
    pub velocity_ned_m_s: Vector3<f64>,
    /// Reported 1-σ accuracies, m.
    pub horizontal_accuracy_m: f64,
    pub vertical_accuracy_m: f64,
    pub satellites: u8,
}

/// The International Standard Atmosphere below 11 km: pressure (hPa) and temperature (°C) at
/// an altitude above mean sea level.
pub fn standard_atmosphere(altitude_m: f64) -> (f64, f64) {
    let temperature_k = 288.15 - 0.0065 * altitude_m;
    let pressure_pa = 101_325.0 * (temperature_k / 288.15).powf(5.255_88);
    (pressure_pa / 100.0, temperature_k - 273.15)
}

/// The altitude of a pressure in the standard atmosphere (the inverse of
/// [`standard_atmosphere`]).
pub fn pressure_altitude_m(pressure_hpa: f64) -> f64 {
    288.15 / 0.0065 * (1.0 - (pressure_hpa / 1013.25).powf(1.0 / 5.255_88))
}

/// The sensor suite of one vehicle.
#[derive(Debug, Clone)]
pub struct Sensors {
    params: SensorParams,
    home: Home,
    rng: SplitMix64,
    accel_bias: [GaussMarkov; 3],
    gyro_bias: [GaussMarkov; 3],
    baro_drift: GaussMarkov,
    gps_drift: [GaussMarkov; 3],
    last_gps_s: Option<f64>,
}

impl Sensors {
    pub fn new(params: SensorParams, home: Home, seed: u64) -> Self {
        let mut rng = SplitMix64::new(seed ^ 0x5345_4e53_4f52);
        let mut process =
            |sigma: f64, tau_s: f64| GaussMarkov::new(sigma, tau_s, rng.next_gaussian());
        let accel_bias = [(); 3].map(|_| process(params.accel_bias_m_s2, params.accel_bias_tau_s));
        let gyro_bias = [(); 3].map(|_| process(params.gyro_bias_rad_s, params.gyro_bias_tau_s));
        let baro_drift = process(params.baro_drift_m, params.baro_drift_tau_s);
        let gps_drift = [
            process(params.gps_drift_horizontal_m, params.gps_drift_tau_s),
            process(params.gps_drift_horizontal_m, params.gps_drift_tau_s),
            process(params.gps_drift_vertical_m, params.gps_drift_tau_s),
        ];
        Self {
            params,
            home,
            rng,
            accel_bias,
            gyro_bias,
            baro_drift,
            gps_drift,
            last_gps_s: None,
        }
    }

    pub fn home(&self) -> &Home {
        &self.home
    }

    fn noise3(&mut self, sigma: f64) -> Vector3<f64> {
        Vector3::new(
            self.rng.next_gaussian(),
            self.rng.next_gaussian(),
            self.rng.next_gaussian(),
        ) * sigma
    }

    /// The IMU, magnetometer and barometer sampled every `dt_s`.
    pub fn imu(&mut self, dt_s: f64, state: &BodyState) -> ImuSample {
        let p = self.params;
        let rate_hz = 1.0 / dt_s.max(1e-6);
        let accel_bias = Vector3::from_fn(|i, _| {
            let g = self.rng.next_gaussian();
            self.accel_bias[i].step(dt_s, g)
        });
        let gyro_bias = Vector3::from_fn(|i, _| {
            let g = self.rng.next_gaussian();
            self.gyro_bias[i].step(dt_s, g)
        });
        let accel = state.specific_force_frd_m_s2()
            + accel_bias
            + self.noise3(p.accel_noise_density * rate_hz.sqrt());
        let gyro =
            state.body_rates_rad_s + gyro_bias + self.noise3(p.gyro_noise_density * rate_hz.sqrt());
        let mag =
            state.attitude.inverse() * p.earth_field_ned_gauss + self.noise3(p.mag_noise_gauss);
        let drift_m = {
            let g = self.rng.next_gaussian();
            self.baro_drift.step(dt_s, g)
        };
        let altitude_m = self.home.altitude_m - state.position_ned_m.z + drift_m;
        let (pressure, temperature_c) = standard_atmosphere(altitude_m);
        let pressure_hpa = pressure + p.baro_noise_hpa * self.rng.next_gaussian();
        ImuSample {
            accel_frd_m_s2: accel,
            gyro_frd_rad_s: gyro,
            mag_frd_gauss: mag,
            pressure_hpa,
            pressure_altitude_m: pressure_altitude_m(pressure_hpa),
            temperature_c,
        }
    }

    /// A GPS fix when one is due at `time_s` (at [`SensorParams::gps_rate_hz`]).
    pub fn gps(&mut self, time_s: f64, state: &BodyState) -> Option<GpsFix> {
        let p = self.params;
        let period_s = 1.0 / p.gps_rate_hz;
        let dt_s = match self.last_gps_s {
            Some(last) if time_s - last < period_s - 1e-9 => return None,
            Some(last) => time_s - last,
            None => period_s,
        };
        self.last_gps_s = Some(time_s);
        let drift = Vector3::from_fn(|i, _| {
            let g = self.rng.next_gaussian();
            self.gps_drift[i].step(dt_s, g)
        });
        let white = Vector3::new(
            p.gps_noise_horizontal_m * self.rng.next_gaussian(),
            p.gps_noise_horizontal_m * self.rng.next_gaussian(),
            p.gps_noise_vertical_m * self.rng.next_gaussian(),
        );
        let (latitude_deg, longitude_deg, altitude_m) =
            self.home.geodetic(&(state.position_ned_m + drift + white));
        let velocity_noise = self.noise3(p.gps_velocity_noise_m_s);
        Some(GpsFix {
            latitude_deg,
            longitude_deg,
            altitude_m,
            velocity_ned_m_s: state.velocity_ned_m_s + velocity_noise,
            horizontal_accuracy_m: p.gps_drift_horizontal_m.hypot(p.gps_noise_horizontal_m),
            vertical_accuracy_m: p.gps_drift_vertical_m.hypot(p.gps_noise_vertical_m),
            satellites: 12,
        })
    }

    /// A rangefinder reading from a true range.
    pub fn rangefinder(&mut self, true_range_m: Option<f64>) -> Option<f64> {
        let noise = self.params.rangefinder_noise_m * self.rng.next_gaussian();
        true_range_m.map(|range| (range + noise).max(0.0))
    }
}

#[cfg(test)]
mod tests;
