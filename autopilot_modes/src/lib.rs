//! PX4's and ArduCopter's flight modes as MAVLink carries them (HEARTBEAT.custom_mode,
//! MAV_CMD_DO_SET_MODE's param2 and param3): the one table the runtime's link and the simulated
//! autopilot share, so that what the link commands and what the simulator obeys cannot drift.
//!
//! PX4 (`src/modules/commander/px4_custom_mode.h`): `custom_mode` is a union whose bytes 2 and 3
//! are `main_mode` and `sub_mode`, i.e. `custom_mode = sub << 24 | main << 16`. Main modes:
//! MANUAL 1, ALTCTL 2, POSCTL 3, AUTO 4, ACRO 5, OFFBOARD 6, STABILIZED 7. AUTO sub modes: READY
//! 1, TAKEOFF 2, LOITER 3, MISSION 4, RTL 5, LAND 6, FOLLOW_TARGET 8, PRECLAND 9. So OFFBOARD =
//! 0x0006_0000, POSCTL = 0x0003_0000, AUTO.TAKEOFF = 0x0204_0000, AUTO.LOITER = 0x0304_0000,
//! AUTO.LAND = 0x0604_0000, AUTO.PRECLAND = 0x0904_0000.
//!
//! ArduCopter (`ArduCopter/mode.h`): plain numbers, GUIDED 4, LOITER 5, LAND 9.

/// PX4's main modes (`PX4_CUSTOM_MAIN_MODE_*`) that qosrt commands or recognises.
const PX4_MAIN_MODE_POSCTL: u8 = 3;
const PX4_MAIN_MODE_AUTO: u8 = 4;
const PX4_MAIN_MODE_OFFBOARD: u8 = 6;

/// The PX4 modes qosrt commands or recognises.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Px4Mode {
    /// POSCTL: the pilot's position mode.
    Position,
    /// OFFBOARD: setpoints from the companion.
    Offboard,
    /// AUTO.TAKEOFF.
    Takeoff,
    /// AUTO.LOITER: hold where it is.
    Loiter,
    /// AUTO.LAND: land where it is.
    Land,
    /// AUTO.PRECLAND: PX4's own precision landing on LANDING_TARGET.
    PrecisionLand,
}

impl Px4Mode {
    /// Every mode of the table.
    pub const ALL: [Px4Mode; 6] = [
        Px4Mode::Position,
        Px4Mode::Offboard,
        Px4Mode::Takeoff,
        Px4Mode::Loiter,
        Px4Mode::Land,
        Px4Mode::PrecisionLand,
    ];

    /// `(main_mode, sub_mode)`: what MAV_CMD_DO_SET_MODE's param2 and param3 carry.
    pub const fn parts(self) -> (u8, u8) {
        match self {
            Px4Mode::Position => (PX4_MAIN_MODE_POSCTL, 0),
            Px4Mode::Offboard => (PX4_MAIN_MODE_OFFBOARD, 0),
            Px4Mode::Takeoff => (PX4_MAIN_MODE_AUTO, 2),
            Px4Mode::Loiter => (PX4_MAIN_MODE_AUTO, 3),
            Px4Mode::Land => (PX4_MAIN_MODE_AUTO, 6),
            Px4Mode::PrecisionLand => (PX4_MAIN_MODE_AUTO, 9),
        }
    }

    /// HEARTBEAT's `custom_mode` for this mode.
    pub const fn custom_mode(self) -> u32 {
        let (main_mode, sub_mode) = self.parts();
        px4_custom_mode(main_mode, sub_mode)
    }

    /// The mode a `custom_mode` names, if the table has it. POSCTL and OFFBOARD have no sub
    /// modes: whatever PX4 leaves in the sub mode byte, they are themselves.
    pub fn from_custom_mode(custom_mode: u32) -> Option<Px4Mode> {
        let (main_mode, sub_mode) = px4_mode_parts(custom_mode);
        Px4Mode::ALL.into_iter().find(|mode| {
            let (main, sub) = mode.parts();
            main == main_mode && (main != PX4_MAIN_MODE_AUTO || sub == sub_mode)
        })
    }
}

/// `custom_mode` for a PX4 main mode and sub mode.
pub const fn px4_custom_mode(main_mode: u8, sub_mode: u8) -> u32 {
    ((sub_mode as u32) << 24) | ((main_mode as u32) << 16)
}

/// `(main_mode, sub_mode)` of a PX4 `custom_mode`.
pub const fn px4_mode_parts(custom_mode: u32) -> (u8, u8) {
    (
        ((custom_mode >> 16) & 0xff) as u8,
        ((custom_mode >> 24) & 0xff) as u8,
    )
}

/// The ArduCopter modes qosrt commands or recognises.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArduCopterMode {
    /// GUIDED: setpoints from the companion.
    Guided,
    /// LOITER: hold where it is.
    Loiter,
    /// LAND: land where it is (precisely, on LANDING_TARGET, with PLND_ENABLED).
    Land,
}

impl ArduCopterMode {
    /// Every mode of the table.
    pub const ALL: [ArduCopterMode; 3] = [
        ArduCopterMode::Guided,
        ArduCopterMode::Loiter,
        ArduCopterMode::Land,
    ];

    /// The mode's number: HEARTBEAT's `custom_mode`, MAV_CMD_DO_SET_MODE's param2.
    pub const fn number(self) -> u32 {
        match self {
            ArduCopterMode::Guided => 4,
            ArduCopterMode::Loiter => 5,
            ArduCopterMode::Land => 9,
        }
    }

    /// The mode a number names, if the table has it.
    pub fn from_number(number: u32) -> Option<ArduCopterMode> {
        ArduCopterMode::ALL
            .into_iter()
            .find(|mode| mode.number() == number)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The values of px4_custom_mode.h's union (main mode in byte 2, sub mode in byte 3), typed
    /// out by hand rather than computed.
    #[test]
    fn px4_custom_modes_are_px4s() {
        let expected = [
            (Px4Mode::Position, 0x0003_0000),
            (Px4Mode::Offboard, 0x0006_0000),
            (Px4Mode::Takeoff, 0x0204_0000),
            (Px4Mode::Loiter, 0x0304_0000),
            (Px4Mode::Land, 0x0604_0000),
            (Px4Mode::PrecisionLand, 0x0904_0000),
        ];
        for (mode, custom_mode) in expected {
            assert_eq!(mode.custom_mode(), custom_mode, "{mode:?}");
            assert_eq!(Px4Mode::from_custom_mode(custom_mode), Some(mode));
        }
        assert_eq!(Px4Mode::Offboard.custom_mode(), 393_216);
        assert_eq!(px4_mode_parts(0x0604_0000), (4, 6));
    }

    #[test]
    fn px4_modes_outside_the_table_are_none() {
        // MANUAL, AUTO.MISSION, AUTO.RTL.
        for custom_mode in [0x0001_0000, 0x0404_0000, 0x0504_0000] {
            assert_eq!(Px4Mode::from_custom_mode(custom_mode), None);
        }
        // OFFBOARD with a stray sub mode byte is still OFFBOARD.
        assert_eq!(
            Px4Mode::from_custom_mode(0x0106_0000),
            Some(Px4Mode::Offboard)
        );
    }

    #[test]
    fn arducopter_numbers_are_mode_h() {
        for (mode, number) in [
            (ArduCopterMode::Guided, 4),
            (ArduCopterMode::Loiter, 5),
            (ArduCopterMode::Land, 9),
        ] {
            assert_eq!(mode.number(), number);
            assert_eq!(ArduCopterMode::from_number(number), Some(mode));
        }
        // STABILIZE, RTL.
        assert_eq!(ArduCopterMode::from_number(0), None);
        assert_eq!(ArduCopterMode::from_number(6), None);
    }
}
