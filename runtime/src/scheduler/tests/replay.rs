//! Deterministic replay: the reference mission's roles over the bus, seeded.

use super::*;

#[derive(Debug, Clone, PartialEq)]
struct Observation {
    id: u64,
    from_seq: u64,
}

/// The reference mission's four roles wired over the bus, with random values from the task seed
/// and step costs drawn from measured samples.
struct Stage {
    rng: SplitMix64,
    input: Option<crate::bus::Subscriber<Observation>>,
    output: Option<crate::bus::Publisher<Observation>>,
    commands: Option<crate::bus::QueueSender<Observation>>,
    received: Option<crate::bus::QueueReceiver<Observation>>,
    record: Record,
}

type Record = Arc<Mutex<Vec<(String, Message<Observation>)>>>;

const MARKER: Topic<Observation> = Topic::new("marker", "Observation");
const RELATIVE: Topic<Observation> = Topic::new("relative_state", "Observation");
const SETPOINTS: Topic<Observation> = Topic::new("setpoints", "Observation");

impl Stage {
    /// The stage's ports for its role: (inputs, outputs).
    fn ports(role: &str) -> (&'static [Port], &'static [Port]) {
        match role {
            "landing_marker" => (&[], const { &[Port::of(MARKER)] }),
            "kalman_tracker" => (
                const { &[Port::of(MARKER)] },
                const { &[Port::of(RELATIVE)] },
            ),
            "landing_guidance" => (
                const { &[Port::of(RELATIVE)] },
                const { &[Port::of(SETPOINTS)] },
            ),
            _ => (const { &[Port::of(SETPOINTS)] }, &[]),
        }
    }

    fn new(role: &'static str, record: Record, build: &TaskBuild<'_>) -> Result<Self, TaskError> {
        let mut stage = Stage {
            rng: SplitMix64::new(0),
            input: None,
            output: None,
            commands: None,
            received: None,
            record,
        };
        match role {
            "landing_marker" => stage.output = Some(build.output(MARKER)?),
            "kalman_tracker" => {
                stage.input = Some(build.input(MARKER)?);
                stage.output = Some(build.output(RELATIVE)?);
            }
            "landing_guidance" => {
                stage.input = Some(build.input(RELATIVE)?);
                stage.commands = Some(build.queue_output(SETPOINTS, QueueSpec::drop_oldest(4))?);
            }
            _ => stage.received = Some(build.queue_input(SETPOINTS, QueueSpec::drop_oldest(4))?),
        }
        Ok(stage)
    }
}

impl Task for Stage {
    fn start(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        self.rng = SplitMix64::new(ctx.seed());
        Ok(())
    }

    fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        let from_seq = match self.input.as_mut() {
            Some(input) => match input.take_new() {
                Some(message) => message.seq,
                None => return Ok(()),
            },
            None => 0,
        };
        let value = Observation {
            id: self.rng.next_u64() % 1000,
            from_seq,
        };
        if let Some(output) = &self.output {
            let seq = output.publish(ctx.now(), value.clone());
            self.record.lock().unwrap().push((
                ctx.name().to_string(),
                Message {
                    stamp: ctx.now(),
                    seq,
                    value,
                },
            ));
        } else if let Some(commands) = &self.commands {
            let _ = commands.send(ctx.now(), value);
        } else if let Some(received) = self.received.as_mut() {
            for message in received.drain() {
                self.record
                    .lock()
                    .unwrap()
                    .push((ctx.name().to_string(), message));
            }
        }
        Ok(())
    }
}

type Replay = (
    Vec<TraceEvent>,
    Vec<(String, Message<Observation>)>,
    Vec<TopicInfo>,
    Vec<TaskStats>,
);

fn replay(seed: u64) -> Replay {
    let record: Record = Arc::default();
    let mut registry = PluginRegistry::new();
    for info in BUILTIN_PLUGINS {
        let record = record.clone();
        let role = info.name;
        let (inputs, outputs) = Stage::ports(role);
        let info = PluginInfo {
            inputs,
            outputs,
            ..info.clone()
        };
        registry
            .register_plugin(info, move |build| {
                Ok(Box::new(Stage::new(role, record.clone(), build)?) as Box<dyn Task>)
            })
            .unwrap();
    }
    // The roles read other topics than the built-in plugins: the reference chain over theirs,
    // detection on its period (here it has no input), tracking and guidance triggered by their
    // inputs as in qos.toml.
    let mut config = reference(&PluginCatalog::builtin());
    config.tasks[0].trigger = crate::config::TaskTrigger::Period;
    config.tasks[1].trigger = crate::config::TaskTrigger::Input(MARKER.name().into());
    config.tasks[2].trigger = crate::config::TaskTrigger::Input(RELATIVE.name().into());
    // Guidance idle on the tracker's period: its idle runs race the triggered ones, which the
    // replay must reproduce too.
    config.tasks[2].max_idle_ms = Some(20.0);
    // Measured step times with a heavy tail, so overruns and skips depend on the draws.
    config.tasks[0].params.insert(
        STEP_COST_PARAM.into(),
        toml::from_str::<toml::Table>(
            "v = [[3.0, 900.0], [3.0, 400.0], [3.0, 250.0], [3.0, 150.0]]",
        )
        .unwrap()["v"]
            .clone(),
    );
    let mut builder = SchedulerBuilder::new(&registry);
    builder.tasks(&config.tasks).seed(seed).record_trace(true);
    let mut scheduler = builder.build_virtual().unwrap();
    scheduler.run_until(Timestamp::from_millis(7_000)).unwrap();
    let tracking = scheduler.task_id("tracking").unwrap();
    let hazard = scheduler.task_id("hazard").unwrap();
    scheduler.set_level(tracking, 0).unwrap();
    scheduler.set_level(hazard, 1).unwrap();
    scheduler.run_until(Timestamp::from_millis(20_000)).unwrap();
    let stats = scheduler.stats();
    let topics = scheduler.bus().topics();
    let trace = scheduler.take_trace();
    drop(scheduler);
    let record = record.lock().unwrap().clone();
    (trace, record, topics, stats)
}

#[test]
fn virtual_replay_is_identical_for_a_seed_and_differs_across_seeds() {
    let first = replay(7);
    let second = replay(7);
    assert!(
        first.0.len() > 1_500,
        "a rich trace: {} events",
        first.0.len()
    );
    assert!(first.1.len() > 250, "many messages: {}", first.1.len());
    assert_eq!(first.0, second.0, "trace of (time, task, event)");
    assert_eq!(
        first.1, second.1,
        "bus messages with stamps and sequence numbers"
    );
    assert_eq!(first.2, second.2, "bus counters");
    assert_eq!(first.3, second.3, "task statistics");
    // The draws matter: the seed changes the messages and the detector's overruns.
    let detection = &first.3[0];
    assert!(
        detection.overruns > 0 && detection.skipped > 0,
        "{detection:?}"
    );
    let other = replay(8);
    assert_ne!(first.0, other.0);
    assert_ne!(first.1, other.1);
    assert!(first
        .0
        .iter()
        .any(|event| event.kind == TraceKind::LevelChanged { level: 0 }
            && event.time == Timestamp::from_millis(7_000)
            && &*event.task == "tracking"));
}
