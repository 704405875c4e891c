//! ArduPilot's own precision landing fed by qosrt's tracker: the real ArduCopter 4.6.3 SITL in
//! `../shared/ardupilot-sitl/` with `PLND_ENABLED=1`, `PLND_TYPE=1`, flown by the runtime's mission
//! runner on the wall clock; the downward camera is rendered by the simulator's camera from the
//! pose ArduPilot reports, looking at a landing pad on the ground 1.5 m north of the take-off
//! point. The runner commands LAND in the last phase and streams LANDING_TARGET from the
//! tracker; ArduPilot steers onto the pad by itself.

use runtime::camera::{CapturedFrame, MemorySource};
use runtime::config::load_file;
use runtime::energy::load_mission_model;
use runtime::link::{LinkConfig, MavlinkLink};
use runtime::mission::{LandingBy, MissionPlan, MissionRunner, RunnerOptions};
use runtime::plugins::builtin_registry;
use runtime::scheduler::{Pinning, RealTimeOptions, SchedulerBuilder};
use runtime::topics::CameraFrame;
use sim::camera::{SimCamera, SimCameraConfig, VehiclePose};
use sim::scene::{PadPose, SimScene};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Where the pad lies, metres north and east of the take-off point.
const PAD_NE_M: [f64; 2] = [1.5, 0.0];

struct ArduPilot(u32);

impl Drop for ArduPilot {
    fn drop(&mut self) {
        let _ = Command::new("kill").arg(self.0.to_string()).status();
    }
}

#[test]
fn ardupilot_precision_landing_follows_the_trackers_landing_target() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let start = root.join("../shared/ardupilot-sitl/start");
    if !start.exists() {
        eprintln!("skipped: {} is absent", start.display());
        return;
    }
    let instance = 2u16;
    let output = Command::new(&start)
        .args(["-I", &instance.to_string(), "-s", "2"])
        .args(["-P", "PLND_ENABLED=1", "-P", "PLND_TYPE=1"])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let _copter = ArduPilot(
        String::from_utf8_lossy(&output.stdout)
            .trim()
            .parse()
            .unwrap(),
    );

    // The reference mission without its landing task (ArduPilot lands) and 4 s of tracking,
    // its camera fixed to the body: ArduPilot's SITL flies no gimbal.
    let text = std::fs::read_to_string(root.join("qos.toml")).unwrap();
    let landing_task = text.find("[[task]]\nname = \"landing\"").unwrap();
    let hazard_task = text.find("[[task]]\nname = \"hazard\"").unwrap();
    let text = format!(
        "{}{}\n[link]\nlanding_target = true\n",
        &text[..landing_task],
        &text[hazard_task..]
    )
    .replace("duration_s = 900.0", "duration_s = 4.0")
    .replace("mount = \"gimbal\"", "mount = \"body\"")
    .replace(
        "path = \"profiles/",
        &format!("path = \"{}/profiles/", root.display()),
    );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("precland.toml");
    std::fs::write(&path, text).unwrap();
    let registry = builtin_registry().unwrap();
    let loaded = load_file(&path, &registry.catalog()).unwrap();
    let model = load_mission_model(&loaded).unwrap();

    let scheduler = SchedulerBuilder::new(&registry)
        .tasks(&loaded.config.tasks)
        .build_real_time(RealTimeOptions {
            pinning: Pinning::Off,
            ..RealTimeOptions::default()
        })
        .unwrap();
    let address = format!("tcpout:127.0.0.1:{}", 5760 + 10 * instance);
    let link = MavlinkLink::connect(&address, LinkConfig::default()).unwrap();
    let mut plan = MissionPlan::for_mission(&loaded.config);
    plan.control = true;
    // No landing task and LANDING_TARGET on: the autopilot lands by its precision landing,
    // qosrt feeds it the target.
    assert_eq!(plan.landing, LandingBy::AutopilotPrecision);
    let frames = MemorySource::new();
    let mut runner = MissionRunner::new(
        model,
        scheduler,
        link,
        plan,
        Some(Box::new(frames.clone())),
        RunnerOptions {
            landing_target: true,
            fixed_levels: Vec::new(),
        },
    )
    .unwrap();

    let mut camera = SimCamera::new(SimCameraConfig::default(), 7).unwrap();
    let mut scene = SimScene::new(7);
    scene
        .set_pad_pose(PadPose {
            north_m: PAD_NE_M[0],
            east_m: PAD_NE_M[1],
            height_m: 0.0,
            yaw_rad: 0.0,
        })
        .unwrap();
    let started = Instant::now();
    let mut landing_targets = 0u64;
    let mut land_started_at = None;
    while !runner.status().finished {
        assert!(
            started.elapsed() < Duration::from_secs(150),
            "{:#?}",
            runner.log().events
        );
        let now_s = runner.scheduler().now().as_secs_f64();
        // The camera sees what the vehicle ArduPilot reports would see.
        let state = runner.link().telemetry().vehicle_state(now_s);
        if let Some(state) = state.filter(|_| camera.is_due(now_s)) {
            let pose = VehiclePose {
                position_ned_m: state.position_ned_m.unwrap_or_default(),
                attitude: state.attitude,
                velocity_ned_m_s: state.velocity_ned_m_s,
                body_rates_rad_s: Default::default(),
            };
            if let Ok(frame) = camera.capture_frame(now_s, &pose, &scene) {
                frames.push(CapturedFrame {
                    frame: CameraFrame {
                        vehicle_at_capture: None,
                        frame_index: frame.frame_index,
                        image: frame.image,
                    },
                    capture_time_s: now_s,
                    arrived_s: now_s,
                });
            }
        }
        let step = runner.step(now_s, None).unwrap();
        if step
            .events
            .iter()
            .any(|e| matches!(e, runtime::mission::MissionEvent::LandingHere { .. }))
        {
            land_started_at = runner.link().telemetry().position_ned_m();
        }
        landing_targets += step
            .commands
            .iter()
            .filter(|c| matches!(c, runtime::link::VehicleCommand::LandingTarget { .. }))
            .count() as u64;
        std::thread::sleep(Duration::from_millis(20));
    }
    runner.stop();
    let events: Vec<&str> = runner
        .log()
        .events
        .iter()
        .map(|(_, e)| e.as_str())
        .collect();
    assert!(events.contains(&"landed and disarmed"), "{events:?}");
    assert!(
        landing_targets > 20,
        "{landing_targets} LANDING_TARGET sent"
    );
    // LAND began over the take-off point, away from the pad ...
    let start = land_started_at.expect("LAND was commanded");
    let start_miss_m = (start.x - PAD_NE_M[0]).hypot(start.y - PAD_NE_M[1]);
    assert!(
        start_miss_m > 1.0,
        "LAND began {start_miss_m:.2} m from the pad"
    );
    // ... and it came down on the pad.
    let position = runner.link().telemetry().position_ned_m().unwrap();
    let miss_m = (position.x - PAD_NE_M[0]).hypot(position.y - PAD_NE_M[1]);
    eprintln!("LAND began {start_miss_m:.2} m from the pad; touched down {miss_m:.2} m from it");
    assert!(
        miss_m < 0.4,
        "touched down at {position:?}, {miss_m:.2} m from the pad: {events:?}"
    );
}
