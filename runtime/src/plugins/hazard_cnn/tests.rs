use super::*;
use crate::bus::Bus;
use crate::clock::Timestamp;
use crate::config::{Knob, TaskConfig};
use crate::inference::InferenceError;
use crate::task::{parse_params, MissionHealth, QosLevel};

fn task(text: &str) -> Result<HazardCnnTask, TaskError> {
    task_on(&Bus::new(), text, None)
}

/// The task on `bus`, as the registry builds it: its params `text`, its config in
/// `config_dir`, on the GPU.
fn task_on(
    bus: &Bus,
    text: &str,
    config_dir: Option<&std::path::Path>,
) -> Result<HazardCnnTask, TaskError> {
    let config = TaskConfig {
        name: "hazard".into(),
        plugin: PLUGIN_NAME.into(),
        resource: Resource::Gpu,
        cores: vec![],
        phases: vec!["tracking".into()],
        weight: 1.0,
        knob: Knob::RateFps,
        levels: vec![1.0],
        utility: vec![1.0],
        restart: None,
        params: toml::from_str(text).unwrap(),
        trigger: Default::default(),
        max_idle_ms: None,
        config_dir: config_dir.map(std::path::Path::to_path_buf),
        camera: Default::default(),
    };
    super::super::build_for_test(&config, bus, |build| {
        HazardCnnTask::new(
            build.parse_params()?,
            build,
            Arc::new(AtomicBool::new(false)),
        )
    })
}

/// What the scheduler gives the task: a bus, the mission's health and its 1 fps level.
struct Harness {
    bus: Bus,
    health: MissionHealth,
    level: QosLevel,
}

impl Harness {
    fn new() -> Self {
        Harness {
            bus: Bus::new(),
            health: MissionHealth::new(vec!["hazard".into()]),
            level: QosLevel {
                index: 0,
                knob: Knob::RateFps,
                value: 1.0,
                period_ms: 1000.0,
            },
        }
    }

    fn context(&self, now: Timestamp) -> TaskContext<'_> {
        TaskContext::new("hazard", now, &self.level, &self.health, 1)
    }
}

/// A level vehicle at `position_ned_m`, over flat ground at the pad's level.
fn level_vehicle(position_ned_m: Vector3<f64>) -> VehicleState {
    VehicleState {
        attitude: Default::default(),
        velocity_ned_m_s: Vector3::zeros(),
        acceleration_ned_m_s2: Vector3::zeros(),
        height_above_pad_m: -position_ned_m.z,
        position_ned_m: Some(position_ned_m),
        landed: false,
        gimbal_attitude: None,
        offboard: true,
    }
}

/// Runs `start` on a fresh bus, as the scheduler would.
fn start(task: &mut HazardCnnTask) -> Result<(), TaskError> {
    task.start(&mut Harness::new().context(Timestamp::ZERO))
}

fn shipped_model_path() -> String {
    concat!(env!("CARGO_MANIFEST_DIR"), "/../models/hazard_yolo.onnx").to_string()
}

#[test]
fn bad_params_are_named() {
    let message = |text: &str| task(text).err().unwrap().to_string();
    assert!(message("classes = []").contains("at least one"));
    assert!(message("confidence_threshold = 1.5").contains("confidence_threshold"));
    assert!(message("iou_threshold = -0.1").contains("iou_threshold"));
    assert!(message("input_width_px = 320").contains("input_height_px"));
    assert!(message("max_detections = 0").contains("max_detections"));
    assert!(message("min_height_m = -1.0").contains("min_height_m"));
    assert!(message("pad_exclusion_radius_m = -1.0").contains("pad_exclusion_radius_m"));
    // The shipped model knows its own classes only.
    let other = message("classes = [\"cow\"]");
    assert!(
        other.contains("person, animal, vehicle") && other.contains("model"),
        "{other}"
    );
    let typo = parse_params::<Params>(&toml::from_str("confidence = 0.5").unwrap())
        .err()
        .unwrap()
        .to_string();
    assert!(typo.contains("confidence"), "{typo}");
}

#[test]
fn a_missing_or_corrupt_model_is_a_named_error_at_start_up() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.onnx");
    let mut hazard = task(&format!("model = {:?}", missing.to_str().unwrap())).unwrap();
    let error = start(&mut hazard).unwrap_err().to_string();
    assert!(
        error.contains("cannot read the model file") && error.contains("missing.onnx"),
        "{error}"
    );
    let corrupt = dir.path().join("corrupt.onnx");
    std::fs::write(
        &corrupt,
        b"\x08\x07garbage that is not a protobuf model\xff\xfe",
    )
    .unwrap();
    let mut hazard = task(&format!("model = {:?}", corrupt.to_str().unwrap())).unwrap();
    let error = start(&mut hazard).unwrap_err().to_string();
    assert!(
        error.contains("not a usable ONNX model") && error.contains("corrupt.onnx"),
        "{error}"
    );
    // Relative paths resolve against the config's folder.
    std::fs::copy(shipped_model_path(), dir.path().join("mine.onnx")).unwrap();
    let mut hazard = task_on(&Bus::new(), "model = \"mine.onnx\"", Some(dir.path())).unwrap();
    start(&mut hazard).unwrap();
}

#[test]
fn a_model_whose_output_does_not_fit_the_classes_is_refused_at_start_up() {
    // The shipped model has 3 classes; told it has 2, its 8-wide rows fit neither layout.
    let text = format!(
        "model = {:?}\nclasses = [\"a\", \"b\"]",
        shipped_model_path()
    );
    let mut hazard = task(&text).unwrap();
    let error = start(&mut hazard).unwrap_err().to_string();
    assert!(error.contains("does not fit 2 classes"), "{error}");
    // Told its input is another size than it was exported with.
    let text = format!(
        "model = {:?}\ninput_width_px = 640\ninput_height_px = 480",
        shipped_model_path()
    );
    let mut hazard = task(&text).unwrap();
    let error = start(&mut hazard).unwrap_err().to_string();
    assert!(
        error.contains("240×320") && error.contains("480×640"),
        "{error}"
    );
}

#[test]
fn without_a_gpu_backend_auto_runs_on_the_cpu_and_says_why() {
    let options = BackendOptions::default();
    let opened = open_backend(&SHIPPED_MODEL, &options).unwrap();
    assert_eq!(opened.backend.name(), "tract-cpu");
    let spec = opened.backend.input();
    assert_eq!(
        (spec.channels, spec.height_px, spec.width_px),
        (1, 240, 320)
    );
    if cfg!(feature = "cuda") {
        // With the feature, whether CUDA is there depends on the machine.
        return;
    }
    let reason = opened.cpu_fallback_reason.unwrap();
    assert!(reason.contains("`cuda` feature"), "{reason}");
    let cuda = BackendOptions {
        choice: BackendChoice::Cuda,
        ..BackendOptions::default()
    };
    assert!(matches!(
        open_backend(&SHIPPED_MODEL, &cuda),
        Err(InferenceError::Unavailable {
            backend: "CUDA",
            ..
        })
    ));
}

#[test]
fn detections_are_placed_on_the_ground_under_the_camera() {
    // Level flight 10 m up at (5, −3): the image centre is straight below, and a pixel
    // offset lands where the pinhole geometry says.
    let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
    let mut vehicle = level_vehicle(Vector3::new(5.0, -3.0, -10.0));
    let (cx, cy) = (camera.cx_px, camera.cy_px);
    let below =
        ground_position_ned_m(&camera, &vehicle.attitude, vehicle.position_ned_m, cx, cy).unwrap();
    assert!(
        (below - Vector3::new(5.0, -3.0, 0.0)).norm() < 1e-9,
        "{below}"
    );
    // 100 px right of centre: tan = 100 / f; with yaw 0 the image's right is east.
    let right = ground_position_ned_m(
        &camera,
        &vehicle.attitude,
        vehicle.position_ned_m,
        cx + 100.0,
        cy,
    )
    .unwrap();
    let expected_east_m = -3.0 + 10.0 * 100.0 / camera.fx_px;
    assert!((right.y - expected_east_m).abs() < 1e-9 && (right.x - 5.0).abs() < 1e-9);
    // Without a position, or on the ground, nothing is placed.
    vehicle.position_ned_m = Some(Vector3::new(5.0, -3.0, 0.0));
    assert!(
        ground_position_ned_m(&camera, &vehicle.attitude, vehicle.position_ned_m, cx, cy).is_none()
    );
    vehicle.position_ned_m = None;
    assert!(
        ground_position_ned_m(&camera, &vehicle.attitude, vehicle.position_ned_m, cx, cy).is_none()
    );
}

/// Pipelined, the task reports on each frame what the synchronous task reports, a step
/// later: the same boxes, placed with the vehicle as it was when the frame was taken up
/// (the vehicle moves between the two steps here), and the frame in flight is reported
/// at the next step even when no new frame has come.
#[test]
fn a_pipelined_task_reports_each_frame_as_the_synchronous_one_a_step_later() {
    // Speckled frames with dark blobs; a low threshold so the shipped model finds boxes.
    let frame_image = |k: u64| {
        let mut state = 0x9e37_79b9_7f4a_7c15u64 ^ k;
        let mut pixels = vec![0u8; 640 * 480];
        for (i, p) in pixels.iter_mut().enumerate() {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let (x, y) = ((i % 640) as i64, (i / 640) as i64);
            let blob = (x - 100 - 60 * k as i64).pow(2) + (y - 240).pow(2) < 400;
            *p = if blob { 20 } else { 110 + (state >> 59) as u8 };
        }
        Arc::new(algorithms::vision::image::GrayImage::from_vec(640, 480, pixels).unwrap())
    };
    let fly = |pipelined: bool| {
        let harness = Harness::new();
        let bus = &harness.bus;
        let mut hazard = task_on(
            bus,
            &format!("confidence_threshold = 0.02\npipelined = {pipelined}"),
            None,
        )
        .unwrap();
        hazard.start(&mut harness.context(Timestamp::ZERO)).unwrap();
        let frames = bus.publisher::<CameraFrame>(CAMERA_FRAME).unwrap();
        let vehicle = bus.publisher::<VehicleState>(VEHICLE_STATE).unwrap();
        let mut reports = bus.subscriber::<HazardReport>(HAZARDS).unwrap();
        let mut published = Vec::new();
        for step in 0..6u64 {
            let now = Timestamp::from_millis(250 * (step + 1));
            vehicle.publish(now, level_vehicle(Vector3::new(step as f64, 0.0, -8.0)));
            // Five frames, then a step with none.
            if step < 5 {
                frames.publish(
                    now,
                    CameraFrame {
                        vehicle_at_capture: None,
                        frame_index: step,
                        image: frame_image(step),
                    },
                );
            }
            hazard.step(&mut harness.context(now)).unwrap();
            if let Some(report) = reports.take_new() {
                published.push((step, report.value.clone()));
            }
        }
        published
    };
    let synchronous = fly(false);
    let pipelined = fly(true);
    assert_eq!(synchronous.len(), 5);
    assert_eq!(pipelined.len(), 5);
    assert!(
        synchronous.iter().any(|(_, r)| !r.detections.is_empty()),
        "no boxes to compare"
    );
    for ((sync_step, sync), (pipe_step, pipe)) in synchronous.iter().zip(&pipelined) {
        assert_eq!(*pipe_step, sync_step + 1);
        assert_eq!(pipe.frame_index, sync.frame_index);
        assert_eq!(pipe.capture_time_s, sync.capture_time_s);
        assert_eq!(pipe.detections, sync.detections);
    }
}

#[test]
fn frames_below_its_height_are_not_looked_at() {
    let harness = Harness::new();
    let bus = &harness.bus;
    let mut hazard = task_on(bus, "", None).unwrap();
    hazard.start(&mut harness.context(Timestamp::ZERO)).unwrap();
    let frames = bus.publisher::<CameraFrame>(CAMERA_FRAME).unwrap();
    let vehicle = bus.publisher::<VehicleState>(VEHICLE_STATE).unwrap();
    let mut reports = bus.subscriber::<HazardReport>(HAZARDS).unwrap();
    let image = Arc::new(algorithms::vision::image::GrayImage::filled(640, 480, 90).unwrap());
    let mut frame_index = 0;
    // One frame at `height_m`: did the task report on it?
    let mut look = |height_m: f64| {
        let now = Timestamp::from_millis(1000 * (frame_index + 1));
        vehicle.publish(now, level_vehicle(Vector3::new(0.0, 0.0, -height_m)));
        frames.publish(
            now,
            CameraFrame {
                vehicle_at_capture: None,
                frame_index,
                image: image.clone(),
            },
        );
        frame_index += 1;
        hazard.step(&mut harness.context(now)).unwrap();
        reports.take_new().is_some()
    };
    assert!(look(8.0));
    assert!(!look(2.0), "below min_height_m");
    assert!(look(4.5));
}
