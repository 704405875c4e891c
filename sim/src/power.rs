//! The simulated pack and what drains it: the rotors' power from the vehicle's state
//! (momentum theory, scaled so hover draws the mission's configured hover power) plus the
//! companion computer's power from the power model at the QoS levels actually running, so
//! the battery the governor sees reflects its own choices.
//!
//! Rotor power at airspeed `V` (horizontal) and climb rate `w` for thrust `T = m·g`:
//!
//! ```text
//! v_i = v_h² / √(V² + v_i²)          induced velocity, v_h = √(T / 2ρA)
//! P   = k · (T·v_i + T·max(w, 0)) + ½·ρ·CdA·V³
//! ```
//!
//! with `k` (electrical/mechanical efficiency factor) chosen so that `P(0, 0)` equals the
//! configured hover power. Descent recovers nothing (`w < 0` adds no power and takes none).

/// Air density at sea level, kg/m³.
const AIR_DENSITY_KG_M3: f64 = 1.225;
const GRAVITY_M_S2: f64 = 9.81;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RotorPowerModel {
    /// Electrical power at hover (the mission's `hover_power_w`).
    pub hover_power_w: f64,
    pub mass_kg: f64,
    /// Total rotor disc area (four 10-inch props: 4·π·0.127²).
    pub disc_area_m2: f64,
    /// Parasitic drag area Cd·A of the airframe.
    pub drag_area_m2: f64,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PowerError {
    #[error("{name} = {value} is invalid: must be a finite number > 0")]
    Invalid { name: &'static str, value: f64 },
    #[error("the pack cannot deliver {power_w:.1} W at state of charge {soc:.3}")]
    PackExhausted { power_w: f64, soc: f64 },
}

impl RotorPowerModel {
    /// An Iris-class quadrotor drawing `hover_power_w` at hover.
    pub fn iris(hover_power_w: f64) -> Self {
        Self {
            hover_power_w,
            mass_kg: 1.5,
            disc_area_m2: 4.0 * std::f64::consts::PI * 0.127 * 0.127,
            drag_area_m2: 0.05,
        }
    }

    pub fn validate(&self) -> Result<(), PowerError> {
        for (name, value) in [
            ("hover_power_w", self.hover_power_w),
            ("mass_kg", self.mass_kg),
            ("disc_area_m2", self.disc_area_m2),
            ("drag_area_m2", self.drag_area_m2),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(PowerError::Invalid { name, value });
            }
        }
        Ok(())
    }

    fn thrust_n(&self) -> f64 {
        self.mass_kg * GRAVITY_M_S2
    }

    /// Induced velocity at hover.
    pub fn hover_induced_velocity_m_s(&self) -> f64 {
        (self.thrust_n() / (2.0 * AIR_DENSITY_KG_M3 * self.disc_area_m2)).sqrt()
    }

    /// Induced velocity at horizontal airspeed `airspeed_m_s` (Glauert, small angle): the
    /// positive root of `v_i⁴ + V²·v_i² − v_h⁴ = 0`.
    pub fn induced_velocity_m_s(&self, airspeed_m_s: f64) -> f64 {
        let v_h = self.hover_induced_velocity_m_s();
        let v2 = airspeed_m_s * airspeed_m_s;
        ((-v2 + (v2 * v2 + 4.0 * v_h.powi(4)).sqrt()) / 2.0).sqrt()
    }

    /// Electrical power at a horizontal airspeed and climb rate (up positive).
    pub fn power_w(&self, airspeed_m_s: f64, climb_m_s: f64) -> f64 {
        let thrust_n = self.thrust_n();
        let efficiency_factor = self.hover_power_w / (thrust_n * self.hover_induced_velocity_m_s());
        let airspeed_m_s = airspeed_m_s.abs();
        let rotor_w = thrust_n * (self.induced_velocity_m_s(airspeed_m_s) + climb_m_s.max(0.0));
        efficiency_factor * rotor_w
            + 0.5 * AIR_DENSITY_KG_M3 * self.drag_area_m2 * airspeed_m_s.powi(3)
    }
}

/// A LiPo cell's resting voltage against its state of charge: the world's own curve (the
/// runtime's battery model is a separate estimate of it, as on a real vehicle).
const LIPO_CELL_OCV: [(f64, f64); 12] = [
    (0.00, 3.27),
    (0.05, 3.61),
    (0.10, 3.69),
    (0.20, 3.73),
    (0.30, 3.77),
    (0.40, 3.79),
    (0.50, 3.83),
    (0.60, 3.87),
    (0.70, 3.94),
    (0.80, 4.01),
    (0.90, 4.10),
    (1.00, 4.20),
];

/// The physical pack: capacity, cells in series and internal resistance; terminal voltage
/// `n·OCV(soc) − I·R`.
#[derive(Debug, Clone, PartialEq)]
pub struct SimPack {
    pub capacity_mah: f64,
    pub cell_count: u32,
    pub internal_resistance_ohm: f64,
}

impl SimPack {
    pub fn new(
        capacity_mah: f64,
        cell_count: u32,
        internal_resistance_ohm: f64,
    ) -> Result<Self, PowerError> {
        for (name, value) in [
            ("capacity_mah", capacity_mah),
            ("cell_count", f64::from(cell_count)),
            ("internal_resistance_ohm", internal_resistance_ohm),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(PowerError::Invalid { name, value });
            }
        }
        Ok(Self {
            capacity_mah,
            cell_count,
            internal_resistance_ohm,
        })
    }

    pub fn capacity_ah(&self) -> f64 {
        self.capacity_mah / 1000.0
    }

    /// Open-circuit voltage of the pack at `soc` (clamped to [0, 1]).
    pub fn pack_ocv_v(&self, soc: f64) -> f64 {
        let soc = soc.clamp(0.0, 1.0);
        let upper = LIPO_CELL_OCV
            .iter()
            .position(|&(s, _)| s >= soc)
            .unwrap_or(LIPO_CELL_OCV.len() - 1)
            .max(1);
        let (s0, v0) = LIPO_CELL_OCV[upper - 1];
        let (s1, v1) = LIPO_CELL_OCV[upper];
        f64::from(self.cell_count) * (v0 + (v1 - v0) * (soc - s0) / (s1 - s0))
    }

    pub fn terminal_voltage_v(&self, soc: f64, current_a: f64) -> f64 {
        self.pack_ocv_v(soc) - current_a * self.internal_resistance_ohm
    }

    /// The current that delivers `power_w` at `soc`: the small root of `E·I − R·I² = P`;
    /// `None` beyond the pack's maximum power `E²/4R`.
    pub fn current_for_power_a(&self, soc: f64, power_w: f64) -> Option<f64> {
        if !(power_w.is_finite() && power_w >= 0.0 && soc.is_finite()) {
            return None;
        }
        let e = self.pack_ocv_v(soc);
        let disc = e * e - 4.0 * self.internal_resistance_ohm * power_w;
        // 2P / (E + √disc) avoids the cancellation of (E − √disc) / 2R.
        (disc >= 0.0).then(|| 2.0 * power_w / (e + disc.sqrt()))
    }
}

/// The pack as the simulation drains it; the autopilot's measurements come from here.
#[derive(Debug, Clone)]
pub struct SimBattery {
    spec: SimPack,
    soc: f64,
    consumed_mah: f64,
    current_a: f64,
    flight_energy_wh: f64,
    companion_energy_wh: f64,
}

impl SimBattery {
    /// A full pack.
    pub fn new(spec: SimPack) -> Self {
        Self {
            spec,
            soc: 1.0,
            consumed_mah: 0.0,
            current_a: 0.0,
            flight_energy_wh: 0.0,
            companion_energy_wh: 0.0,
        }
    }

    /// Drains the pack for `dt_s` at the given loads.
    pub fn drain(
        &mut self,
        flight_power_w: f64,
        companion_power_w: f64,
        dt_s: f64,
    ) -> Result<(), PowerError> {
        let power_w = flight_power_w + companion_power_w;
        let current_a =
            self.spec
                .current_for_power_a(self.soc, power_w)
                .ok_or(PowerError::PackExhausted {
                    power_w,
                    soc: self.soc,
                })?;
        self.current_a = current_a;
        self.consumed_mah += current_a * dt_s / 3.6;
        self.soc -= current_a * dt_s / 3600.0 / self.spec.capacity_ah();
        self.flight_energy_wh += flight_power_w * dt_s / 3600.0;
        self.companion_energy_wh += companion_power_w * dt_s / 3600.0;
        Ok(())
    }

    pub fn soc(&self) -> f64 {
        self.soc
    }

    pub fn voltage_v(&self) -> f64 {
        self.spec.terminal_voltage_v(self.soc, self.current_a)
    }

    pub fn current_a(&self) -> f64 {
        self.current_a
    }

    pub fn consumed_mah(&self) -> f64 {
        self.consumed_mah
    }

    /// Energy delivered to the rotors and to the companion computer so far.
    pub fn energy_wh(&self) -> (f64, f64) {
        (self.flight_energy_wh, self.companion_energy_wh)
    }

    /// The autopilot's reading: what a power module measures, and PX4's remaining estimate
    /// from the consumed charge.
    pub fn reading(&self) -> crate::flight::BatteryReading {
        crate::flight::BatteryReading {
            voltage_v: self.voltage_v(),
            current_a: self.current_a,
            consumed_mah: self.consumed_mah,
            remaining_fraction: (1.0 - self.consumed_mah / self.spec.capacity_mah).clamp(0.0, 1.0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hover_draws_the_configured_power_and_cruise_draws_less() {
        let model = RotorPowerModel::iris(165.0);
        model.validate().unwrap();
        assert!((model.power_w(0.0, 0.0) - 165.0).abs() < 1e-9);
        // Translational lift: at moderate speed the induced power falls faster than drag
        // rises; at high speed drag wins.
        let cruise_w = model.power_w(5.0, 0.0);
        assert!(cruise_w < 165.0, "{cruise_w}");
        assert!(model.power_w(25.0, 0.0) > 165.0);
        // Climb adds k·T·w: at 1 m/s, 165 W / v_h per m/s.
        let v_h = model.hover_induced_velocity_m_s();
        let climb_w = model.power_w(0.0, 1.0) - 165.0;
        assert!((climb_w - 165.0 / v_h).abs() < 1e-6, "{climb_w}");
        assert_eq!(model.power_w(0.0, -1.0), 165.0);
    }

    /// The root satisfies Glauert's momentum equation itself, and its two limits: v_h at
    /// hover, v_h²/V at high speed.
    #[test]
    fn induced_velocity_solves_the_momentum_equation() {
        let model = RotorPowerModel::iris(165.0);
        let v_h = model.hover_induced_velocity_m_s();
        // T = 2ρA·v_h² for 1.5 kg and four 10-inch discs.
        let thrust_n = 2.0 * 1.225 * model.disc_area_m2 * v_h * v_h;
        assert!((thrust_n - 1.5 * 9.81).abs() < 1e-9);
        for airspeed in [0.0, 1.0, 3.0, 8.0, 15.0] {
            let v_i = model.induced_velocity_m_s(airspeed);
            let momentum = v_h * v_h / (airspeed * airspeed + v_i * v_i).sqrt();
            assert!(
                (v_i - momentum).abs() < 1e-9,
                "{airspeed}: {v_i} vs {momentum}"
            );
        }
        assert!((model.induced_velocity_m_s(0.0) - v_h).abs() < 1e-12);
        let fast = model.induced_velocity_m_s(100.0);
        assert!((fast - v_h * v_h / 100.0).abs() < 1e-3 * fast);
    }

    #[test]
    fn the_pack_voltage_follows_the_cell_curve() {
        let pack = SimPack::new(5000.0, 4, 0.025).unwrap();
        assert!((pack.pack_ocv_v(1.0) - 16.8).abs() < 1e-12);
        assert!((pack.pack_ocv_v(0.0) - 13.08).abs() < 1e-12);
        // Halfway between 50 % (3.83 V) and 60 % (3.87 V).
        assert!((pack.pack_ocv_v(0.55) - 4.0 * 3.85).abs() < 1e-12);
        assert!((pack.terminal_voltage_v(0.55, 20.0) - (15.4 - 0.5)).abs() < 1e-12);
        assert!(SimPack::new(0.0, 4, 0.025).is_err());
    }

    /// Draining at constant power uses the energy the OCV curve holds between the two states
    /// of charge, plus the resistive loss: compare with a fine independent integration.
    #[test]
    fn the_pack_drains_as_its_model_says() {
        let spec = SimPack::new(5000.0, 4, 0.025).unwrap();
        let mut pack = SimBattery::new(spec.clone());
        for _ in 0..6000 {
            pack.drain(160.0, 10.0, 0.1).unwrap();
        }
        // 600 s at 170 W.
        let (flight_wh, companion_wh) = pack.energy_wh();
        assert!((flight_wh - 160.0 * 600.0 / 3600.0).abs() < 1e-9);
        assert!((companion_wh - 10.0 * 600.0 / 3600.0).abs() < 1e-9);
        // Independent: chemical energy n·∫OCV dQ between the states of charge equals the load
        // energy plus the I²R loss.
        let mut chemical_wh = 0.0;
        let (soc_end, steps) = (pack.soc(), 20000);
        for i in 0..steps {
            let soc = soc_end + (1.0 - soc_end) * (i as f64 + 0.5) / steps as f64;
            chemical_wh += spec.pack_ocv_v(soc) * (1.0 - soc_end) / steps as f64 * 5.0;
        }
        let loss_wh = pack.current_a().powi(2) * 0.025 * 600.0 / 3600.0;
        let load_wh = flight_wh + companion_wh;
        assert!(
            (chemical_wh - load_wh - loss_wh).abs() < 0.02 * load_wh,
            "chemical {chemical_wh} vs load {load_wh} + loss {loss_wh}"
        );
        let reading = pack.reading();
        assert!((reading.voltage_v - pack.voltage_v()).abs() < 1e-12);
        assert!(reading.remaining_fraction < 1.0 && reading.remaining_fraction > 0.0);
        assert!(matches!(
            SimBattery::new(spec).drain(1e7, 0.0, 0.1),
            Err(PowerError::PackExhausted { .. })
        ));
    }
}
