use super::*;
use mavlink::dialects::common::{
    MavBatteryFunction, MavBatteryType, MavDistanceSensor, MavSysStatusSensor, COMMAND_ACK_DATA,
    EXTENDED_SYS_STATE_DATA,
};

fn heartbeat(autopilot: MavAutopilot, base_mode: MavModeFlag, custom_mode: u32) -> HEARTBEAT_DATA {
    HEARTBEAT_DATA {
        custom_mode,
        mavtype: MavType::MAV_TYPE_QUADROTOR,
        autopilot,
        base_mode,
        system_status: MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    }
}

#[test]
fn heartbeat_decodes_px4_and_ardupilot_modes_and_armed() {
    let custom = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
    let armed = custom | MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
    let px4 = |mode| decode_heartbeat(&heartbeat(MavAutopilot::MAV_AUTOPILOT_PX4, armed, mode));
    assert_eq!(px4(0x0006_0000).unwrap().mode, AutopilotMode::Offboard);
    assert!(px4(0x0006_0000).unwrap().armed);
    assert_eq!(px4(0x0604_0000).unwrap().mode, AutopilotMode::Land);
    assert_eq!(px4(0x0904_0000).unwrap().mode, AutopilotMode::Land);
    assert_eq!(px4(0x0204_0000).unwrap().mode, AutopilotMode::Takeoff);
    assert_eq!(px4(0x0304_0000).unwrap().mode, AutopilotMode::Hold);
    assert_eq!(px4(0x0003_0000).unwrap().mode, AutopilotMode::Position);
    assert_eq!(
        px4(0x0404_0000).unwrap().mode,
        AutopilotMode::Other {
            custom_mode: 0x0404_0000
        }
    );
    let disarmed = decode_heartbeat(&heartbeat(
        MavAutopilot::MAV_AUTOPILOT_PX4,
        custom,
        0x0006_0000,
    ))
    .unwrap();
    assert!(!disarmed.armed);
    let ardu = |mode| {
        decode_heartbeat(&heartbeat(
            MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            custom,
            mode,
        ))
        .unwrap()
    };
    assert_eq!(ardu(4).mode, AutopilotMode::Offboard);
    assert_eq!(ardu(9).mode, AutopilotMode::Land);
    assert_eq!(ardu(5).mode, AutopilotMode::Hold);
    assert_eq!(ardu(5).kind, AutopilotKind::ArduPilot);
    // Without the custom-mode flag the number is not a custom mode.
    let plain = decode_heartbeat(&heartbeat(
        MavAutopilot::MAV_AUTOPILOT_PX4,
        MavModeFlag::empty(),
        0x0006_0000,
    ))
    .unwrap();
    assert_eq!(
        plain.mode,
        AutopilotMode::Other {
            custom_mode: 0x0006_0000
        }
    );
    // A ground station's heartbeat is not the autopilot's.
    assert!(decode_heartbeat(&heartbeat(MavAutopilot::MAV_AUTOPILOT_INVALID, custom, 0)).is_none());
}

fn battery_status(
    cells: [u16; 10],
    current_ca: i16,
    consumed: i32,
    remaining: i8,
) -> BATTERY_STATUS_DATA {
    BATTERY_STATUS_DATA {
        current_consumed: consumed,
        energy_consumed: -1,
        temperature: i16::MAX,
        voltages: cells,
        current_battery: current_ca,
        id: 0,
        battery_function: MavBatteryFunction::MAV_BATTERY_FUNCTION_ALL,
        mavtype: MavBatteryType::MAV_BATTERY_TYPE_LIPO,
        battery_remaining: remaining,
        ..Default::default()
    }
}

#[test]
fn battery_status_cells_and_sentinels() {
    let mut cells = [u16::MAX; 10];
    cells[..4].copy_from_slice(&[3950; 4]);
    let telemetry = battery_from_battery_status(&battery_status(cells, -1, -1, -1), 3.0);
    assert!((telemetry.voltage_v.unwrap() - 15.8).abs() < 1e-12);
    assert_eq!(telemetry.current_a, None);
    assert_eq!(telemetry.consumed_mah, None);
    assert_eq!(telemetry.remaining_fraction, None);
    assert_eq!(telemetry.time_s, 3.0);

    let measured = battery_from_battery_status(&battery_status(cells, 1234, 420, 80), 0.0);
    assert_eq!(measured.current_a, Some(12.34));
    assert_eq!(measured.consumed_mah, Some(420.0));
    assert_eq!(measured.remaining_fraction, Some(0.8));

    // Overflow form: cell 0 = 65534 mV, cell 1 = the rest.
    let mut big = [u16::MAX; 10];
    big[0] = u16::MAX - 1;
    big[1] = 1_466;
    let no_extension = [0u16; 4];
    assert_eq!(pack_voltage_from_cells(&big, &no_extension), Some(67.0));
    // A 12S pack: ten cells, then cells 11 and 12 in voltages_ext (0: no cell).
    let many = [3_900u16; 10];
    let extension = [3_900, 3_900, 0, 0];
    let volts = pack_voltage_from_cells(&many, &extension).unwrap();
    assert!((volts - 12.0 * 3.9).abs() < 1e-9, "{volts}");
    assert_eq!(
        pack_voltage_from_cells(&[u16::MAX; 10], &no_extension),
        None
    );
}

fn sys_status(voltage_mv: u16, current_ca: i16, remaining: i8) -> SYS_STATUS_DATA {
    SYS_STATUS_DATA {
        onboard_control_sensors_present: MavSysStatusSensor::empty(),
        onboard_control_sensors_enabled: MavSysStatusSensor::empty(),
        onboard_control_sensors_health: MavSysStatusSensor::empty(),
        load: 0,
        voltage_battery: voltage_mv,
        current_battery: current_ca,
        drop_rate_comm: 0,
        errors_comm: 0,
        errors_count1: 0,
        errors_count2: 0,
        errors_count3: 0,
        errors_count4: 0,
        battery_remaining: remaining,
        ..Default::default()
    }
}

#[test]
fn sys_status_sentinels() {
    let unknown = battery_from_sys_status(&sys_status(u16::MAX, -1, -1), 1.0).unwrap();
    assert_eq!(unknown.voltage_v, None);
    assert_eq!(unknown.current_a, None);
    assert_eq!(unknown.remaining_fraction, None);
    let known = battery_from_sys_status(&sys_status(15_800, 2_050, 55), 1.0).unwrap();
    assert_eq!(known.voltage_v, Some(15.8));
    assert_eq!(known.current_a, Some(20.5));
    assert_eq!(known.remaining_fraction, Some(0.55));
    assert_eq!(known.consumed_mah, None);
}

#[test]
fn a_battery_monitor_present_but_not_enabled_is_no_reading() {
    // ArduCopter 4.6.3 SITL's sensor bits, recorded by `qosrt run`: with BATT_MONITOR = 0 the
    // battery (bit 25) is present but not enabled, at 0 V; with its default monitor, enabled.
    let with_bits = |present: u32, enabled: u32| SYS_STATUS_DATA {
        onboard_control_sensors_present: MavSysStatusSensor::from_bits_truncate(present),
        onboard_control_sensors_enabled: MavSysStatusSensor::from_bits_truncate(enabled),
        ..sys_status(0, -1, -1)
    };
    let off = with_bits(0x5371_fc0f, 0x5041_9c0f);
    assert_eq!(battery_from_sys_status(&off, 1.0), None);
    let mut state = TelemetryState::new();
    let applied = state.apply(&MavMessage::SYS_STATUS(off), 1.0);
    assert!(!applied.battery);
    assert_eq!(state.battery(), None);
    let on = SYS_STATUS_DATA {
        voltage_battery: 12_600,
        ..with_bits(0x5371_fc0f, 0x5241_9c0f)
    };
    assert_eq!(
        battery_from_sys_status(&on, 1.0).and_then(|b| b.voltage_v),
        Some(12.6)
    );
}

#[test]
fn battery_status_wins_over_sys_status_and_borrows_its_voltage() {
    let mut state = TelemetryState::new();
    state.apply(&MavMessage::SYS_STATUS(sys_status(16_000, 1_000, 90)), 1.0);
    assert_eq!(state.battery().unwrap().voltage_v, Some(16.0));
    let applied = state.apply(
        &MavMessage::BATTERY_STATUS(battery_status([u16::MAX; 10], 900, 100, 89)),
        2.0,
    );
    assert!(applied.battery);
    let battery = state.battery().unwrap();
    assert_eq!(battery.voltage_v, Some(16.0));
    assert_eq!(battery.consumed_mah, Some(100.0));
    let later = state.apply(&MavMessage::SYS_STATUS(sys_status(15_000, 1_000, 80)), 3.0);
    assert!(!later.battery);
    assert_eq!(state.battery().unwrap().time_s, 2.0);
}

fn distance(current_cm: u16, orientation: MavSensorOrientation) -> DISTANCE_SENSOR_DATA {
    DISTANCE_SENSOR_DATA {
        time_boot_ms: 0,
        min_distance: 10,
        max_distance: 4_000,
        current_distance: current_cm,
        mavtype: MavDistanceSensor::MAV_DISTANCE_SENSOR_LASER,
        id: 0,
        orientation,
        covariance: 0,
        ..Default::default()
    }
}

/// A beam that slips off the 1 m pad onto the field does not make the vehicle 1 m higher.
#[test]
fn the_height_above_the_pad_ignores_the_beam_slipping_onto_the_ground() {
    let mut state = TelemetryState::new();
    state.apply(
        &MavMessage::ATTITUDE(ATTITUDE_DATA {
            time_boot_ms: 0,
            roll: 0.0,
            pitch: 0.0,
            yaw: 0.0,
            rollspeed: 0.0,
            pitchspeed: 0.0,
            yawspeed: 0.0,
        }),
        0.0,
    );
    let at_height = |z_m: f32| {
        MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
            time_boot_ms: 0,
            x: 0.0,
            y: 0.0,
            z: z_m,
            vx: 0.0,
            vy: 0.0,
            vz: 0.0,
        })
    };
    let range = |cm| {
        MavMessage::DISTANCE_SENSOR(distance(
            cm,
            MavSensorOrientation::MAV_SENSOR_ROTATION_PITCH_270,
        ))
    };
    // Climbing out over the field, then over the pad at 3 m: 2 m above it.
    state.apply(&at_height(-0.5), 0.0);
    state.apply(&range(50), 0.0);
    state.apply(&at_height(-3.0), 1.0);
    state.apply(&range(300), 1.0);
    state.apply(&range(200), 1.1);
    let height_m = |state: &TelemetryState| state.vehicle_state(1.2).unwrap().height_above_pad_m;
    assert!(
        (height_m(&state) - 2.0).abs() < 1e-6,
        "{}",
        height_m(&state)
    );
    // The beam slips off the pad: still 2 m above it, where the raw reading says 3.
    state.apply(&range(300), 1.2);
    assert!(
        (height_m(&state) - 2.0).abs() < 0.01,
        "{}",
        height_m(&state)
    );
}

#[test]
fn the_gimbals_attitude_in_either_yaw_frame_until_it_goes_stale() {
    // A camera held looking straight down, its image top towards `heading`: the gimbal's
    // quaternion Rz(heading)·Ry(−90°), multiplied out by hand.
    let looking_down = |heading_rad: f64| {
        let k = std::f64::consts::FRAC_1_SQRT_2;
        let (s, c) = (heading_rad / 2.0).sin_cos();
        [k * c, k * s, -k * c, k * s].map(|v| v as f32)
    };
    let status = |q: [f32; 4], flags| {
        MavMessage::GIMBAL_DEVICE_ATTITUDE_STATUS(GIMBAL_DEVICE_ATTITUDE_STATUS_DATA {
            q,
            flags,
            ..Default::default()
        })
    };
    let mut state = TelemetryState::new();
    state.apply(
        &MavMessage::ATTITUDE(ATTITUDE_DATA {
            roll: 0.3,
            yaw: 1.2,
            ..Default::default()
        }),
        0.0,
    );
    state.apply(
        &MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA::default()),
        0.0,
    );
    assert_eq!(state.vehicle_state(0.0).unwrap().gimbal_attitude, None);
    let close = |a: Attitude, heading: f64| {
        a.roll_rad.abs() < 1e-6 && a.pitch_rad.abs() < 1e-6 && (a.yaw_rad - heading).abs() < 1e-6
    };
    // The camera's attitude the vehicle state gives right after a status at `now_s`.
    let mut report = |q, flags, now_s| {
        assert!(state.apply(&status(q, flags), now_s).vehicle_state);
        state.vehicle_state(now_s).unwrap().gimbal_attitude.unwrap()
    };
    let earth = GimbalDeviceFlags::GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME;
    let camera = report(looking_down(1.5), earth, 0.0);
    assert!(close(camera, 1.5), "{camera:?}");
    // Relative to the vehicle's heading (1.2 rad): 0.3 rad more.
    let vehicle_frame = GimbalDeviceFlags::GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME;
    let camera = report(looking_down(0.3), vehicle_frame, 0.1);
    assert!(close(camera, 1.5), "{camera:?}");
    // Without a frame flag: earth with YAW_LOCK (old gimbals), else the vehicle's.
    let camera = report(looking_down(0.3), GimbalDeviceFlags::empty(), 0.2);
    assert!(close(camera, 1.5), "{camera:?}");
    let lock = GimbalDeviceFlags::GIMBAL_DEVICE_FLAGS_YAW_LOCK;
    let camera = report(looking_down(0.3), lock, 0.3);
    assert!(close(camera, 0.3), "{camera:?}");
    // A gimbal that stops reporting is not used past GIMBAL_STALE_S…
    assert!(state
        .vehicle_state(0.3 + GIMBAL_STALE_S + 0.01)
        .unwrap()
        .gimbal_attitude
        .is_none());
    // …nor one that reports no attitude (MAVLink's NaN).
    state.apply(&status([f32::NAN; 4], earth), 1.0);
    assert_eq!(state.vehicle_state(1.0).unwrap().gimbal_attitude, None);
}

#[test]
fn vehicle_state_from_attitude_position_rangefinder_and_landed() {
    let mut state = TelemetryState::new();
    assert!(state.vehicle_state(0.0).is_none());
    state.apply(
        &MavMessage::ATTITUDE(ATTITUDE_DATA {
            time_boot_ms: 0,
            roll: 0.1,
            pitch: -0.2,
            yaw: 1.5,
            rollspeed: 0.0,
            pitchspeed: 0.0,
            yawspeed: 0.0,
        }),
        0.0,
    );
    let position = |ms, vx: f32| {
        MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
            time_boot_ms: ms,
            x: 1.0,
            y: 2.0,
            z: -5.0,
            vx,
            vy: 0.0,
            vz: 0.5,
        })
    };
    assert!(state.apply(&position(1_000, 1.0), 0.0).vehicle_state);
    state.apply(&position(1_020, 1.2), 0.02);
    let vehicle = state.vehicle_state(0.02).unwrap();
    assert_eq!(vehicle.attitude.roll_rad, f64::from(0.1f32));
    assert_eq!(vehicle.attitude.pitch_rad, f64::from(-0.2f32));
    assert_eq!(vehicle.attitude.yaw_rad, f64::from(1.5f32));
    assert!((vehicle.acceleration_ned_m_s2.x - 10.0).abs() < 1e-4);
    assert_eq!(vehicle.velocity_ned_m_s.z, 0.5);
    // No rangefinder yet: −z.
    assert_eq!(vehicle.height_above_pad_m, 5.0);
    state.apply(
        &MavMessage::DISTANCE_SENSOR(distance(
            400,
            MavSensorOrientation::MAV_SENSOR_ROTATION_PITCH_270,
        )),
        0.02,
    );
    let expected = 4.0 * f64::from(0.1f32).cos() * f64::from(-0.2f32).cos();
    let height_m =
        |state: &TelemetryState, now_s| state.vehicle_state(now_s).unwrap().height_above_pad_m;
    assert!((height_m(&state, 0.02) - expected).abs() < 1e-12);
    // Stale rangefinder: the surface it saw is where it was (the autopilot's altitude
    // above that level), not the home point.
    assert!((height_m(&state, 1.0) - expected).abs() < 1e-12);
    // A forward-looking sensor is not the downward one.
    state.apply(
        &MavMessage::DISTANCE_SENSOR(distance(
            100,
            MavSensorOrientation::MAV_SENSOR_ROTATION_NONE,
        )),
        1.0,
    );
    assert!((height_m(&state, 1.0) - expected).abs() < 1e-12);
    // Out of range clears the reading, not the level: UINT16_MAX, or the maximum itself,
    // which is how PX4 forwards "no return" (a vehicle on the ground below the minimum
    // reads 15 m there, and taken as a reading it sank the ground level 15 m).
    for no_return_cm in [u16::MAX, 4_000] {
        state.apply(
            &MavMessage::DISTANCE_SENSOR(distance(
                no_return_cm,
                MavSensorOrientation::MAV_SENSOR_ROTATION_PITCH_270,
            )),
            1.0,
        );
        assert!((height_m(&state, 1.0) - expected).abs() < 1e-12);
    }
    let reading = |cm| {
        rangefinder_height_m(
            &distance(cm, MavSensorOrientation::MAV_SENSOR_ROTATION_PITCH_270),
            &Attitude::new(0.0, 0.0, 0.0),
        )
    };
    assert_eq!(reading(3_999), Some(39.99));
    assert_eq!(reading(10), Some(0.1));
    assert_eq!((reading(4_000), reading(9)), (None, None));
    let landed = |landed_state| {
        MavMessage::EXTENDED_SYS_STATE(EXTENDED_SYS_STATE_DATA {
            vtol_state: mavlink::dialects::common::MavVtolState::MAV_VTOL_STATE_MC,
            landed_state,
        })
    };
    state.apply(&landed(MavLandedState::MAV_LANDED_STATE_ON_GROUND), 1.0);
    assert!(state.vehicle_state(1.0).unwrap().landed);
    state.apply(&landed(MavLandedState::MAV_LANDED_STATE_UNDEFINED), 1.0);
    assert!(state.vehicle_state(1.0).unwrap().landed);
    state.apply(&landed(MavLandedState::MAV_LANDED_STATE_IN_AIR), 1.0);
    assert!(!state.vehicle_state(1.0).unwrap().landed);
    // Offboard as the last heartbeat says: not before one, then PX4 OFFBOARD, then a
    // pilot's switch to POSCTL.
    assert!(!state.vehicle_state(1.0).unwrap().offboard);
    let custom = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
    for (mode, offboard) in [(0x0006_0000, true), (0x0003_0000, false)] {
        state.apply(
            &MavMessage::HEARTBEAT(heartbeat(MavAutopilot::MAV_AUTOPILOT_PX4, custom, mode)),
            1.0,
        );
        assert_eq!(state.vehicle_state(1.0).unwrap().offboard, offboard);
    }
}

#[test]
fn command_ack_is_surfaced() {
    let mut state = TelemetryState::new();
    let applied = state.apply(
        &MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
            command: MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
            result: MavResult::MAV_RESULT_DENIED,
            ..Default::default()
        }),
        0.0,
    );
    assert_eq!(
        applied.ack,
        Some(CommandAck {
            command_id: 400,
            result: AckResult::Denied
        })
    );
}

#[test]
fn commands_encode_as_px4_expects() {
    let target = CommandTarget {
        system_id: 1,
        component_id: 1,
        kind: AutopilotKind::Px4,
        home_amsl_m: Some(488.0),
    };
    // Take-off: PX4 above mean sea level, ArduPilot above home, PX4 without home: NaN.
    let takeoff_param7 = |target: &CommandTarget| match command_message(
        &VehicleCommand::Takeoff { altitude_m: 8.5 },
        target,
        0,
    ) {
        MavMessage::COMMAND_LONG(long) => long.param7,
        other => panic!("not a COMMAND_LONG: {other:?}"),
    };
    assert_eq!(takeoff_param7(&target), 496.5);
    let no_home = CommandTarget {
        home_amsl_m: None,
        ..target
    };
    assert!(takeoff_param7(&no_home).is_nan());
    let ardupilot_takeoff = CommandTarget {
        kind: AutopilotKind::ArduPilot,
        ..target
    };
    assert_eq!(takeoff_param7(&ardupilot_takeoff), 8.5);
    let MavMessage::COMMAND_LONG(interval) = command_message(
        &VehicleCommand::SetMessageInterval {
            message_id: 147,
            interval_us: 500_000,
        },
        &target,
        0,
    ) else {
        panic!("not a COMMAND_LONG");
    };
    assert_eq!(interval.command, MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL);
    assert_eq!((interval.param1, interval.param2), (147.0, 500_000.0));
    let velocity = command_message(
        &VehicleCommand::VelocityNed {
            velocity_ned_m_s: Vector3::new(1.0, -2.0, 0.5),
            yaw_rad: None,
        },
        &target,
        7,
    );
    let MavMessage::SET_POSITION_TARGET_LOCAL_NED(setpoint) = velocity else {
        panic!("not a setpoint: {velocity:?}");
    };
    // X|Y|Z|AX|AY|AZ|YAW|YAW_RATE ignored = 1+2+4+64+128+256+1024+2048.
    assert_eq!(setpoint.type_mask.bits(), 3_527);
    assert_eq!(setpoint.coordinate_frame, MavFrame::MAV_FRAME_LOCAL_NED);
    assert_eq!((setpoint.vx, setpoint.vy, setpoint.vz), (1.0, -2.0, 0.5));
    assert_eq!(velocity_type_mask(true).bits(), 3_527 - 1_024);

    let MavMessage::COMMAND_LONG(offboard) =
        command_message(&VehicleCommand::SetOffboard, &target, 0)
    else {
        panic!("not a COMMAND_LONG");
    };
    assert_eq!(offboard.command, MavCmd::MAV_CMD_DO_SET_MODE);
    assert_eq!(
        (offboard.param1, offboard.param2, offboard.param3),
        (1.0, 6.0, 0.0)
    );
    let MavMessage::COMMAND_LONG(hold) = command_message(&VehicleCommand::SetHold, &target, 0)
    else {
        panic!("not a COMMAND_LONG");
    };
    assert_eq!((hold.param2, hold.param3), (4.0, 3.0));
    let ardupilot = CommandTarget {
        kind: AutopilotKind::ArduPilot,
        ..target
    };
    let MavMessage::COMMAND_LONG(guided) =
        command_message(&VehicleCommand::SetOffboard, &ardupilot, 0)
    else {
        panic!("not a COMMAND_LONG");
    };
    assert_eq!(guided.param2, 4.0);
    // The autopilot's own precision landing: PX4 AUTO.PRECLAND (main 4, sub 9), ArduPilot
    // LAND (9), which lands precisely when PLND_ENABLED.
    for (autopilot, mode) in [(&target, (4.0, 9.0)), (&ardupilot, (9.0, 0.0))] {
        let MavMessage::COMMAND_LONG(precland) =
            command_message(&VehicleCommand::PrecisionLand, autopilot, 0)
        else {
            panic!("not a COMMAND_LONG");
        };
        assert_eq!(precland.command, MavCmd::MAV_CMD_DO_SET_MODE);
        assert_eq!((precland.param2, precland.param3), mode);
    }
    let MavMessage::COMMAND_LONG(arm) = command_message(&VehicleCommand::Arm, &target, 0) else {
        panic!("not a COMMAND_LONG");
    };
    assert_eq!(
        (arm.command, arm.param1),
        (MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    );
    assert_eq!(VehicleCommand::Land.command_id(), Some(21));
    assert_eq!(
        VehicleCommand::Takeoff { altitude_m: 3.0 }.command_id(),
        Some(22)
    );
}
