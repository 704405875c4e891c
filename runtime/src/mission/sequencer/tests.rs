//! The sequencer against a minimal obedient autopilot.

use super::*;
use algorithms::control::landing::LandingMode;

fn plan() -> MissionPlan {
    let mut plan = MissionPlan::new(
        vec!["transit".into(), "tracking".into(), "landing".into()],
        vec![0.0, 30.0, 0.0],
    );
    plan.meeting_point_ne_m = [20.0, 0.0];
    plan
}

/// A minimal autopilot that obeys at once: arming, take-off (climbs 2 m/s), offboard and
/// velocity setpoints, land. Enough to walk the sequencer through a mission.
struct Obedient {
    view: AutopilotView,
    velocity: Vector3<f64>,
    streamed_s: f64,
    /// Precision landings asked for: it lands on the second (a slow autopilot).
    precision_lands: usize,
}

impl Obedient {
    fn new() -> Self {
        Self {
            view: AutopilotView {
                kind: AutopilotKind::Px4,
                armed: false,
                mode: AutopilotMode::Hold,
                landed: true,
                position_ned_m: Vector3::zeros(),
            },
            velocity: Vector3::zeros(),
            streamed_s: 0.0,
            precision_lands: 0,
        }
    }

    fn apply(&mut self, commands: &[VehicleCommand], dt_s: f64) {
        for command in commands {
            match *command {
                VehicleCommand::Arm => self.view.armed = true,
                VehicleCommand::Takeoff { .. } if self.view.armed => {
                    self.view.mode = AutopilotMode::Takeoff;
                    self.view.landed = false;
                }
                VehicleCommand::Takeoff { .. } => {}
                VehicleCommand::SetOffboard => {
                    assert!(self.streamed_s > 0.0, "offboard before any setpoint");
                    self.view.mode = AutopilotMode::Offboard;
                }
                VehicleCommand::VelocityNed {
                    velocity_ned_m_s, ..
                } => {
                    self.velocity = velocity_ned_m_s;
                    self.streamed_s += dt_s;
                }
                VehicleCommand::Land => self.view.mode = AutopilotMode::Land,
                VehicleCommand::PrecisionLand => {
                    self.precision_lands += 1;
                    if self.precision_lands >= 2 {
                        self.view.mode = AutopilotMode::Land;
                    }
                }
                other => panic!("the sequencer never sends {other:?}"),
            }
        }
        match self.view.mode {
            AutopilotMode::Takeoff if self.view.position_ned_m.z > -8.5 => {
                self.view.position_ned_m.z -= 2.0 * dt_s;
            }
            AutopilotMode::Offboard => self.view.position_ned_m += self.velocity * dt_s,
            AutopilotMode::Land => {
                self.view.armed = false;
                self.view.landed = true;
            }
            _ => {}
        }
    }
}

fn landing(mode: LandingMode, down_m_s: f64) -> LandingSetpoint {
    LandingSetpoint {
        mode,
        velocity_setpoint_ned_m_s: Vector3::new(1.5, 0.0, down_m_s),
    }
}

#[test]
fn walks_through_the_phases_to_touchdown() {
    let mut sequencer = MissionSequencer::new(plan());
    let mut autopilot = Obedient::new();
    let dt_s = 0.05;
    let mut all_events = Vec::new();
    let mut phase_starts = Vec::new();
    for k in 0..4000 {
        let time_s = k as f64 * dt_s;
        let phase = sequencer.status().phase;
        // The landing task follows in tracking and touches down 5 s into landing.
        let setpoint = match phase {
            Some(2) if time_s - sequencer.status().phase_started_s > 5.0 => {
                Some(landing(LandingMode::Landed, 0.0))
            }
            Some(1) | Some(2) => Some(landing(LandingMode::Follow, 0.0)),
            _ => None,
        };
        let (commands, events) = sequencer.step(&SequencerInput {
            time_s,
            link_up: true,
            autopilot: Some(autopilot.view),
            landing: setpoint,
            land_now: None,
        });
        for event in &events {
            if let MissionEvent::PhaseStarted { phase, .. } = event {
                phase_starts.push((*phase, time_s));
            }
        }
        all_events.extend(events);
        autopilot.apply(&commands, dt_s);
        if sequencer.status().finished {
            break;
        }
    }
    assert!(sequencer.status().finished, "{all_events:?}");
    assert_eq!(
        phase_starts.iter().map(|p| p.0).collect::<Vec<_>>(),
        vec![0, 1, 2]
    );
    // Transit ends over the meeting point: 20 m north at the cruise height.
    let tracking_s = phase_starts[2].1 - phase_starts[1].1;
    assert!((tracking_s - 30.0).abs() <= dt_s + 1e-9, "{tracking_s}");
    assert!(all_events.contains(&MissionEvent::Touchdown));
    let order: Vec<_> = all_events
        .iter()
        .filter(|e| {
            matches!(
                e,
                MissionEvent::Armed | MissionEvent::TookOff | MissionEvent::OffboardEngaged
            )
        })
        .collect();
    assert_eq!(
        order,
        vec![
            &MissionEvent::Armed,
            &MissionEvent::TookOff,
            &MissionEvent::OffboardEngaged
        ]
    );
}

#[test]
fn transit_flies_to_the_meeting_point_and_then_tracking_begins() {
    let mut sequencer = MissionSequencer::new(plan());
    let mut autopilot = Obedient::new();
    let dt_s = 0.05;
    for k in 0..2000 {
        let time_s = k as f64 * dt_s;
        let (commands, _) = sequencer.step(&SequencerInput {
            time_s,
            link_up: true,
            autopilot: Some(autopilot.view),
            landing: None,
            land_now: None,
        });
        if let Some(VehicleCommand::VelocityNed {
            velocity_ned_m_s, ..
        }) = commands
            .iter()
            .find(|c| matches!(c, VehicleCommand::VelocityNed { .. }))
        {
            assert!(velocity_ned_m_s.norm() <= 3.0 + 1e-9);
        }
        autopilot.apply(&commands, dt_s);
        if sequencer.status().phase == Some(1) {
            let p = autopilot.view.position_ned_m;
            assert!((p.x - 20.0).hypot(p.y) <= 0.5 + 0.2, "{p:?}");
            assert!((p.z + 8.5).abs() < 0.5, "{p:?}");
            return;
        }
    }
    panic!("never reached the meeting point");
}

#[test]
fn link_loss_stops_commands_and_recovery_reenters_offboard() {
    let mut sequencer = MissionSequencer::new(plan());
    let mut autopilot = Obedient::new();
    let dt_s = 0.05;
    let mut lost_events = 0;
    let mut restored = false;
    let mut reentered = false;
    for k in 0..3000 {
        let time_s = k as f64 * dt_s;
        let in_tracking = sequencer.status().phase == Some(1);
        let link_up = !(in_tracking && (30.0..33.0).contains(&time_s));
        let (commands, events) = sequencer.step(&SequencerInput {
            time_s,
            link_up,
            autopilot: Some(autopilot.view),
            landing: Some(landing(LandingMode::Follow, 0.0)),
            land_now: None,
        });
        if !link_up {
            assert!(commands.is_empty(), "sent {commands:?} without a link");
            // The autopilot fails safe on its own.
            autopilot.view.mode = AutopilotMode::Hold;
        }
        for event in &events {
            match event {
                MissionEvent::LinkLost => lost_events += 1,
                MissionEvent::LinkRestored => restored = true,
                MissionEvent::OffboardEngaged if restored => reentered = true,
                _ => {}
            }
        }
        autopilot.apply(&commands, dt_s);
        if reentered {
            break;
        }
    }
    assert_eq!(lost_events, 1);
    assert!(
        reentered,
        "offboard was not re-entered after the link came back"
    );
    assert_eq!(sequencer.status().phase, Some(1), "the phase goes on");
}

#[test]
fn land_now_skips_to_the_landing_phase_and_refusals_abort() {
    let mut sequencer = MissionSequencer::new(plan());
    let mut autopilot = Obedient::new();
    let dt_s = 0.05;
    let mut time_s = 0.0;
    while sequencer.status().phase != Some(1) {
        let (commands, _) = sequencer.step(&SequencerInput {
            time_s,
            link_up: true,
            autopilot: Some(autopilot.view),
            landing: None,
            land_now: None,
        });
        autopilot.apply(&commands, dt_s);
        time_s += dt_s;
        assert!(time_s < 100.0);
    }
    let (_, events) = sequencer.step(&SequencerInput {
        time_s,
        link_up: true,
        autopilot: Some(autopilot.view),
        landing: Some(landing(LandingMode::Follow, 0.0)),
        land_now: Some("battery"),
    });
    assert!(events.contains(&MissionEvent::LandNow {
        reason: "battery".into()
    }));
    assert_eq!(sequencer.status().phase, Some(2));

    // An autopilot that never arms: the sequencer retries, then gives up.
    let mut stubborn = MissionSequencer::new(plan());
    let view = Obedient::new().view;
    let mut arms = 0;
    let mut aborted = false;
    for k in 0..1000 {
        let (commands, events) = stubborn.step(&SequencerInput {
            time_s: k as f64 * dt_s,
            link_up: true,
            autopilot: Some(view),
            landing: None,
            land_now: None,
        });
        arms += commands
            .iter()
            .filter(|c| **c == VehicleCommand::Arm)
            .count();
        aborted |= events
            .iter()
            .any(|e| matches!(e, MissionEvent::Aborted { .. }));
    }
    assert!(aborted);
    assert!((25..=35).contains(&arms), "{arms} arm commands in 30 s");
    assert!(stubborn.status().finished);
}

/// Steps the sequencer against the obedient autopilot until `until` holds or 200 s pass.
fn fly_until(
    sequencer: &mut MissionSequencer,
    autopilot: &mut Obedient,
    time_s: &mut f64,
    until: impl Fn(&MissionSequencer, &Obedient) -> bool,
) -> Vec<MissionEvent> {
    let dt_s = 0.05;
    let mut events = Vec::new();
    while !until(sequencer, autopilot) {
        let (commands, new_events) = sequencer.step(&SequencerInput {
            time_s: *time_s,
            link_up: true,
            autopilot: Some(autopilot.view),
            landing: Some(landing(LandingMode::Follow, 0.0)),
            land_now: None,
        });
        events.extend(new_events);
        autopilot.apply(&commands, dt_s);
        *time_s += dt_s;
        assert!(*time_s < 200.0, "never got there: {events:?}");
    }
    events
}

#[test]
fn observe_mode_commands_nothing_and_follows_the_flight() {
    let mut observer = MissionSequencer::new(MissionPlan {
        control: false,
        ..plan()
    });
    let mut view = Obedient::new().view;
    let mut phases = Vec::new();
    for k in 0..2000 {
        let time_s = k as f64 * 0.05;
        // The pilot arms and takes off at 10 s, lands at 80 s.
        view.armed = (10.0..80.0).contains(&time_s);
        view.landed = !view.armed;
        let (commands, events) = observer.step(&SequencerInput {
            time_s,
            link_up: true,
            autopilot: Some(view),
            landing: Some(landing(LandingMode::Follow, -1.0)),
            land_now: Some("battery"),
        });
        assert!(commands.is_empty(), "observe mode sent {commands:?}");
        for event in events {
            if let MissionEvent::PhaseStarted { phase, .. } = event {
                phases.push((phase, time_s));
            }
        }
    }
    assert!(!observer.status().holds_control);
    // Airborne at 10 s; transit's configured 0 s, tracking 30 s; on the ground at 80 s.
    assert_eq!(phases.iter().map(|p| p.0).collect::<Vec<_>>(), [0, 1, 2]);
    assert!((phases[0].1 - 10.0).abs() < 0.06, "{phases:?}");
    assert!(
        (phases[2].1 - phases[1].1 - 30.0).abs() < 0.06,
        "{phases:?}"
    );
    assert!(observer.status().finished);
}

#[test]
fn a_mode_change_by_someone_else_stops_commanding_at_once() {
    let mut sequencer = MissionSequencer::new(plan());
    let mut autopilot = Obedient::new();
    let mut time_s = 0.0;
    fly_until(&mut sequencer, &mut autopilot, &mut time_s, |s, _| {
        s.status().phase == Some(1)
    });
    assert!(sequencer.status().holds_control);
    // A ground station switches to position mode.
    autopilot.view.mode = AutopilotMode::Position;
    let (commands, events) = sequencer.step(&SequencerInput {
        time_s,
        link_up: true,
        autopilot: Some(autopilot.view),
        landing: Some(landing(LandingMode::Follow, 0.0)),
        land_now: Some("battery"),
    });
    assert!(commands.is_empty(), "{commands:?}");
    assert_eq!(
        events,
        [
            MissionEvent::LandNow {
                reason: "battery".into()
            },
            MissionEvent::TakenOver {
                mode: AutopilotMode::Position
            }
        ]
    );
    // Never again, whatever the mode does next.
    for k in 1..100 {
        autopilot.view.mode = AutopilotMode::Offboard;
        let (commands, _) = sequencer.step(&SequencerInput {
            time_s: time_s + k as f64 * 0.05,
            link_up: true,
            autopilot: Some(autopilot.view),
            landing: Some(landing(LandingMode::Follow, 0.0)),
            land_now: None,
        });
        assert!(commands.is_empty());
    }
    assert!(!sequencer.status().holds_control);
    // A stop now has nothing to land.
    assert_eq!(sequencer.request_landing("time up").0, []);
}

#[test]
fn a_stop_lands_where_the_vehicle_is_and_waits_for_disarm() {
    let mut sequencer = MissionSequencer::new(plan());
    let mut autopilot = Obedient::new();
    let mut time_s = 0.0;
    fly_until(&mut sequencer, &mut autopilot, &mut time_s, |s, _| {
        s.status().phase == Some(1)
    });
    let (commands, events) = sequencer.request_landing("--duration-s ran out");
    assert_eq!(commands, [VehicleCommand::Land]);
    assert!(matches!(events[..], [MissionEvent::LandingHere { .. }]));
    let events = fly_until(&mut sequencer, &mut autopilot, &mut time_s, |s, _| {
        s.status().finished
    });
    assert!(events.contains(&MissionEvent::Disarmed), "{events:?}");
    assert!(!events
        .iter()
        .any(|e| matches!(e, MissionEvent::TakenOver { .. })));
}

#[test]
fn without_a_camera_the_last_phase_lands_with_the_autopilot() {
    let mut sequencer = MissionSequencer::new(MissionPlan {
        landing: LandingBy::Autopilot,
        ..plan()
    });
    let mut autopilot = Obedient::new();
    let mut time_s = 0.0;
    let events = fly_until(&mut sequencer, &mut autopilot, &mut time_s, |s, _| {
        s.status().finished
    });
    let landing_at = events
        .iter()
        .position(|e| matches!(e, MissionEvent::LandingHere { .. }))
        .expect("landed by the autopilot");
    let last_phase_at = events
        .iter()
        .position(|e| matches!(e, MissionEvent::PhaseStarted { phase: 2, .. }))
        .unwrap();
    assert!(last_phase_at < landing_at);
    assert_eq!(events.last(), Some(&MissionEvent::Disarmed));
}

/// No landing task and LANDING_TARGETs on: the last phase is the autopilot's precision
/// landing, asked again (the same one, not its plain land) until the autopilot is in it.
#[test]
fn the_autopilot_lands_by_its_precision_landing_when_asked() {
    let mut sequencer = MissionSequencer::new(MissionPlan {
        landing: LandingBy::AutopilotPrecision,
        ..plan()
    });
    let mut autopilot = Obedient::new();
    let mut time_s = 0.0;
    let events = fly_until(&mut sequencer, &mut autopilot, &mut time_s, |s, _| {
        s.status().finished
    });
    assert_eq!(autopilot.precision_lands, 2, "{events:?}");
    let reason = events
        .iter()
        .find_map(|e| match e {
            MissionEvent::LandingHere { reason } => Some(reason.as_str()),
            _ => None,
        })
        .expect("landed by the autopilot");
    assert!(reason.contains("precision"), "{reason}");
    assert_eq!(events.last(), Some(&MissionEvent::Disarmed));
    assert!(!events
        .iter()
        .any(|e| matches!(e, MissionEvent::TakenOver { .. })));
}

/// The plan says who lands from the config: the landing task when it flies the last phase,
/// else the autopilot, by its precision landing when `[link] landing_target` is on.
#[test]
fn the_plan_takes_who_lands_from_the_config() {
    let reference = include_str!("../../../../qos.toml");
    let catalog = crate::catalog::PluginCatalog::builtin();
    let landing_by = |text: &str| {
        let config = crate::config::load_str(text, None, &catalog).unwrap();
        MissionPlan::for_mission(&config).landing
    };
    let landing_task = reference.find("[[task]]\nname = \"landing\"").unwrap();
    let hazard_task = reference.find("[[task]]\nname = \"hazard\"").unwrap();
    let without = format!(
        "{}{}",
        &reference[..landing_task],
        &reference[hazard_task..]
    );
    let targets = "\n[link]\nlanding_target = true\n";
    assert_eq!(landing_by(reference), LandingBy::Vision);
    assert_eq!(
        landing_by(&format!("{reference}{targets}")),
        LandingBy::Vision
    );
    assert_eq!(landing_by(&without), LandingBy::Autopilot);
    assert_eq!(
        landing_by(&format!("{without}{targets}")),
        LandingBy::AutopilotPrecision
    );
}

#[test]
fn ardupilot_enters_guided_before_arming() {
    let mut sequencer = MissionSequencer::new(plan());
    let mut view = Obedient::new().view;
    view.kind = AutopilotKind::ArduPilot;
    view.mode = AutopilotMode::Other { custom_mode: 0 };
    let input = |view: AutopilotView, time_s: f64| SequencerInput {
        time_s,
        link_up: true,
        autopilot: Some(view),
        landing: None,
        land_now: None,
    };
    let (commands, _) = sequencer.step(&input(view, 0.0));
    assert_eq!(commands, [VehicleCommand::SetOffboard]);
    view.mode = AutopilotMode::Offboard;
    let (commands, _) = sequencer.step(&input(view, 0.1));
    assert_eq!(commands, [VehicleCommand::Arm]);
}

#[test]
fn after_a_takeover_a_lost_and_restored_link_does_not_bring_control_back() {
    let mut sequencer = MissionSequencer::new(plan());
    let mut autopilot = Obedient::new();
    let mut time_s = 0.0;
    fly_until(&mut sequencer, &mut autopilot, &mut time_s, |s, _| {
        s.status().phase == Some(1)
    });
    autopilot.view.mode = AutopilotMode::Position;
    let mut step = |link_up: bool, time_s: f64| {
        sequencer.step(&SequencerInput {
            time_s,
            link_up,
            autopilot: Some(autopilot.view),
            landing: Some(landing(LandingMode::Follow, 0.0)),
            land_now: None,
        })
    };
    let (_, events) = step(true, time_s);
    assert!(matches!(events[..], [MissionEvent::TakenOver { .. }]));
    // The link drops, then comes back: restored, but nothing is sent and control stays away.
    for k in 1..=40 {
        let link_up = k > 20;
        let (commands, _) = step(link_up, time_s + k as f64 * 0.05);
        assert!(commands.is_empty(), "{commands:?}");
    }
    assert!(!sequencer.status().holds_control);
}
