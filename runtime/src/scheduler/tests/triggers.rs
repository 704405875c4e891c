//! Input-triggered tasks: a chain answers its input within one pass, never above its rate cap.

use super::*;
use crate::bus::{Publisher, Subscriber};
use crate::config::TaskTrigger;

const FRAME: Topic<u64> = Topic::new("test/frame", "u64");
const FIX: Topic<u64> = Topic::new("test/fix", "u64");
const STATE: Topic<u64> = Topic::new("test/state", "u64");
const SETPOINT: Topic<u64> = Topic::new("test/setpoint", "u64");

/// Relays the newest input to its output, keeping the input's stamp (the capture time), and
/// logs each activation with the value it relayed (or none).
struct Relay {
    input: Subscriber<u64>,
    output: Publisher<u64>,
    log: RelayLog,
    cost_ms: u64,
}

impl Task for Relay {
    fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        let message = self.input.take_new();
        self.log.lock().unwrap().push((
            ctx.name().to_string(),
            ctx.now(),
            message.as_ref().map(|m| m.value),
        ));
        if let Some(message) = message {
            self.output.publish(message.stamp, message.value);
        }
        if self.cost_ms > 0 {
            ctx.report_step_cost(Duration::from_millis(self.cost_ms));
        }
        Ok(())
    }
}

#[derive(serde::Deserialize)]
struct RelayParams {
    #[serde(default)]
    cost_ms: u64,
}

type RelayLog = Arc<Mutex<Vec<(String, Timestamp, Option<u64>)>>>;

/// detection (frame → fix), tracking (fix → state), guidance (state → setpoint).
fn relays() -> (PluginRegistry, RelayLog) {
    let log = RelayLog::default();
    let mut registry = PluginRegistry::new();
    for (name, input, output) in [
        ("detect", FRAME, FIX),
        ("track", FIX, STATE),
        ("guide", STATE, SETPOINT),
    ] {
        let log = log.clone();
        let info = PluginInfo {
            inputs: match name {
                "detect" => const { &[Port::of(FRAME)] },
                "track" => const { &[Port::of(FIX)] },
                _ => const { &[Port::of(STATE)] },
            },
            outputs: match name {
                "detect" => const { &[Port::of(FIX)] },
                "track" => const { &[Port::of(STATE)] },
                _ => const { &[Port::of(SETPOINT)] },
            },
            ..PluginInfo::user(name)
        };
        registry
            .register_plugin(info, move |build| {
                let params: RelayParams = build.parse_params()?;
                Ok(Box::new(Relay {
                    input: build.input(input)?,
                    output: build.output(output)?,
                    log: log.clone(),
                    cost_ms: params.cost_ms,
                }))
            })
            .unwrap();
    }
    (registry, log)
}

fn relay(name: &str, trigger: Option<Topic<u64>>, period_ms: f64, params: &str) -> TaskConfig {
    TaskConfig {
        plugin: name.into(),
        trigger: trigger.map_or(TaskTrigger::Period, |t| {
            TaskTrigger::Input(t.name().to_string())
        }),
        ..probe(name, Knob::PeriodMs, &[period_ms], params)
    }
}

fn chain(triggered: bool, period_ms: f64, params: &str) -> Vec<TaskConfig> {
    let on = |topic| triggered.then_some(topic);
    vec![
        relay("detect", on(FRAME), period_ms, params),
        relay("track", on(FIX), period_ms, params),
        relay("guide", on(STATE), period_ms, params),
    ]
}

fn runs_of(log: &RelayLog, task: &str) -> Vec<(u64, Option<u64>)> {
    log.lock()
        .unwrap()
        .iter()
        .filter(|(name, _, _)| name == task)
        .map(|(_, at, value)| (at.as_nanos() / MS, *value))
        .collect()
}

#[test]
fn a_triggered_chain_answers_each_frame_in_the_pass_that_delivers_it() {
    let (registry, log) = relays();
    let mut builder = SchedulerBuilder::new(&registry);
    builder.tasks(&chain(true, 20.0, ""));
    let mut scheduler = builder.build_virtual().unwrap();
    let frames = scheduler.bus().publisher(FRAME).unwrap();
    let mut setpoints = scheduler.bus().subscriber(SETPOINT).unwrap();
    // Frames every 100 ms, captured 30 ms before they are delivered; the loop passes every 5 ms.
    for tick in 0..=100u64 {
        let now_ms = tick * 5;
        if now_ms % 100 == 50 {
            frames.publish(Timestamp::from_millis(now_ms - 30), now_ms);
        }
        scheduler.run_until(Timestamp::from_millis(now_ms)).unwrap();
        if now_ms % 100 == 50 {
            let answer = setpoints
                .take_new()
                .expect("the frame answered in its pass");
            assert_eq!(answer.value, now_ms);
            assert_eq!(answer.stamp, Timestamp::from_millis(now_ms - 30));
        } else {
            assert!(setpoints.take_new().is_none(), "nothing but frames runs it");
        }
    }
    // Each task ran exactly once per frame, at its delivery, on it.
    let expected: Vec<_> = (0..5).map(|k| (50 + 100 * k, Some(50 + 100 * k))).collect();
    for task in ["detect", "track", "guide"] {
        assert_eq!(runs_of(&log, task), expected, "{task}");
        let stats = scheduler.task_stats(task).unwrap();
        assert_eq!((stats.activations, stats.dropped_inputs), (5, 0));
    }
}

#[test]
fn a_periodic_chain_waits_for_each_task_s_tick() {
    // The baseline the trigger removes: on 20 ms periods the frame waits at every stage.
    let (registry, _log) = relays();
    let mut builder = SchedulerBuilder::new(&registry);
    builder.tasks(&chain(false, 20.0, ""));
    let mut scheduler = builder.build_virtual().unwrap();
    let frames = scheduler.bus().publisher(FRAME).unwrap();
    let mut setpoints = scheduler.bus().subscriber(SETPOINT).unwrap();
    scheduler.run_until(Timestamp::from_millis(45)).unwrap();
    frames.publish(Timestamp::from_millis(45), 1);
    scheduler.run_until(Timestamp::from_millis(50)).unwrap();
    assert!(setpoints.take_new().is_none());
    // detect at 60, track and guide after it in that pass (config order breaks the tie).
    scheduler.run_until(Timestamp::from_millis(60)).unwrap();
    assert_eq!(setpoints.take_new().map(|m| m.value), Some(1));
}

#[test]
fn step_costs_delay_each_stage_by_the_one_before() {
    let (registry, log) = relays();
    let mut builder = SchedulerBuilder::new(&registry);
    builder.tasks(&chain(true, 20.0, "cost_ms = 2"));
    let mut scheduler = builder.build_virtual().unwrap();
    scheduler.start().unwrap();
    let frames = scheduler.bus().publisher(FRAME).unwrap();
    frames.publish(Timestamp::from_millis(7), 1);
    scheduler.run_until(Timestamp::from_millis(10)).unwrap();
    scheduler.run_until(Timestamp::from_millis(20)).unwrap();
    assert_eq!(runs_of(&log, "detect"), vec![(10, Some(1))]);
    assert_eq!(runs_of(&log, "track"), vec![(12, Some(1))]);
    assert_eq!(runs_of(&log, "guide"), vec![(14, Some(1))]);
}

#[test]
fn the_level_caps_a_triggered_task_s_rate_and_counts_what_it_drops() {
    let (registry, log) = relays();
    let mut builder = SchedulerBuilder::new(&registry);
    // Detection capped at 2 fps on a 10 fps camera.
    builder.task(&TaskConfig {
        knob: Knob::RateFps,
        levels: vec![2.0],
        ..relay("detect", Some(FRAME), 0.0, "")
    });
    let mut scheduler = builder.build_virtual().unwrap();
    // Started first: a message published before the start is not the task's.
    scheduler.start().unwrap();
    let frames = scheduler.bus().publisher(FRAME).unwrap();
    for k in 0..20u64 {
        let now_ms = 100 * k;
        frames.publish(Timestamp::from_millis(now_ms), now_ms);
        scheduler.run_until(Timestamp::from_millis(now_ms)).unwrap();
    }
    // The credit's two runs at once, then one run each 500 ms, each on the newest frame.
    let runs = runs_of(&log, "detect");
    assert_eq!(
        runs,
        [0, 100, 500, 1_000, 1_500].map(|t| (t, Some(t))).to_vec()
    );
    assert!(runs.len() as u64 <= 1_900 / 500 + 2);
    let stats = scheduler.task_stats("detect").unwrap();
    // 20 frames: 5 taken, the 11 superseded before a take dropped, the last 4 still waiting
    // for the credit.
    assert_eq!((stats.activations, stats.dropped_inputs), (5, 11));
}

#[test]
fn an_idle_triggered_task_runs_on_its_own_but_an_input_is_answered_at_once() {
    let (registry, log) = relays();
    let mut builder = SchedulerBuilder::new(&registry);
    builder.task(&TaskConfig {
        max_idle_ms: Some(50.0),
        ..relay("track", Some(FIX), 20.0, "")
    });
    let mut scheduler = builder.build_virtual().unwrap();
    let fixes = scheduler.bus().publisher(FIX).unwrap();
    scheduler.run_until(Timestamp::from_millis(100)).unwrap();
    // 3 ms after its idle run at 100 ms, a fix: answered at once, not 17 ms later.
    fixes.publish(Timestamp::from_millis(100), 7);
    scheduler.run_until(Timestamp::from_millis(103)).unwrap();
    scheduler.run_until(Timestamp::from_millis(200)).unwrap();
    assert_eq!(
        runs_of(&log, "track"),
        vec![
            (50, None),
            (100, None),
            (103, Some(7)),
            (153, None),
            // Idle from 153 ms: never more often than its idle time.
        ]
    );
}

#[test]
fn a_level_change_while_an_input_waits_runs_it_now_not_in_the_past() {
    let (registry, log) = relays();
    let mut builder = SchedulerBuilder::new(&registry);
    builder.task_with(
        &TaskConfig {
            knob: Knob::RateFps,
            levels: vec![1.0, 4.0],
            ..relay("detect", Some(FRAME), 0.0, "")
        },
        TaskOptions {
            initial_level: Some(0),
            ..TaskOptions::default()
        },
    );
    let mut scheduler = builder.build_virtual().unwrap();
    scheduler.start().unwrap();
    let frames = scheduler.bus().publisher(FRAME).unwrap();
    // Two frames spend the credit at 1 fps; a third, noticed at 20 ms, waits for it (1010 ms).
    for (at_ms, value) in [(0, 1), (10, 2), (20, 3)] {
        frames.publish(Timestamp::from_millis(at_ms), value);
        scheduler.run_until(Timestamp::from_millis(at_ms)).unwrap();
    }
    scheduler.run_until(Timestamp::from_millis(600)).unwrap();
    // At 4 fps it would have been due at 250 ms, already past: it runs now.
    let detect = scheduler.task_id("detect").unwrap();
    scheduler.set_level(detect, 1).unwrap();
    scheduler.run_until(Timestamp::from_millis(3_000)).unwrap();
    assert_eq!(
        runs_of(&log, "detect"),
        vec![(0, Some(1)), (10, Some(2)), (600, Some(3))]
    );
}

#[test]
fn triggered_virtual_runs_replay_exactly() {
    let run = || {
        let (registry, log) = relays();
        let mut builder = SchedulerBuilder::new(&registry);
        builder.tasks(&chain(true, 20.0, "cost_ms = 1"));
        builder.record_trace(true);
        let mut scheduler = builder.build_virtual().unwrap();
        let frames = scheduler.bus().publisher(FRAME).unwrap();
        for tick in 0..200u64 {
            if tick % 7 == 3 {
                frames.publish(Timestamp::from_millis(tick * 5), tick);
            }
            scheduler
                .run_until(Timestamp::from_millis(tick * 5))
                .unwrap();
        }
        let trace = scheduler.take_trace();
        let log = log.lock().unwrap().clone();
        (trace, log)
    };
    let (first, second) = (run(), run());
    assert!(first.1.len() > 80, "{}", first.1.len());
    assert_eq!(first, second);
}

#[test]
fn a_real_time_triggered_chain_answers_a_frame_long_before_any_period() {
    let (registry, log) = relays();
    let mut builder = SchedulerBuilder::new(&registry);
    // 1 s periods: a periodic chain would answer in up to 3 s.
    builder.tasks(&chain(true, 1_000.0, ""));
    let mut scheduler = builder.build_real_time(unpinned()).unwrap();
    scheduler.start().unwrap();
    let frames = scheduler.bus().publisher(FRAME).unwrap();
    let mut setpoints = scheduler.bus().subscriber(SETPOINT).unwrap();
    std::thread::sleep(Duration::from_millis(50));
    // Two frames, each answered at once (the credit holds two runs).
    for value in [41, 42] {
        let sent = Instant::now();
        frames.publish(scheduler.now(), value);
        let answer = loop {
            if let Some(answer) = setpoints.take_new() {
                break answer;
            }
            assert!(sent.elapsed() < Duration::from_millis(500), "no answer");
            std::thread::sleep(Duration::from_micros(200));
        };
        assert_eq!(answer.value, value);
    }
    // A burst with the credit spent: taken once, when a run's credit is back, on the newest.
    for value in 43..=46 {
        frames.publish(scheduler.now(), value);
    }
    std::thread::sleep(Duration::from_millis(1_300));
    scheduler.stop();
    let detect = runs_of(&log, "detect");
    assert_eq!(
        detect.iter().map(|(_, v)| *v).collect::<Vec<_>>(),
        vec![Some(41), Some(42), Some(46)]
    );
    assert!(
        detect[2].0 - detect[0].0 >= 1_000,
        "the cap holds: {detect:?}"
    );
    assert_eq!(scheduler.task_stats("detect").unwrap().dropped_inputs, 3);
}
