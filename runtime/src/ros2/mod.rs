//! The runtime as a ROS 2 node (feature `ros2`): the vehicle's state, the battery, the velocity
//! setpoint, the phase, the governor's decisions and every task's level and statistics,
//! published under `/qosrt/<vehicle>/` with ROS 2's standard message types, over DDS
//! (RustDDS, through `ros2-client`: pure Rust, nothing of ROS installed to build or run).
//!
//! The mission loop only queues what happened; the node's own thread encodes and publishes, as
//! the recorder's does. QoS as ROS 2 users expect it: what streams (pose, battery, setpoint)
//! best-effort and volatile, as `rclcpp::SensorDataQoS`; what is state (phase, levels, the
//! governor's decisions) reliable and transient-local, so a late subscriber gets the last one.

pub mod messages;
mod publishers;

pub use publishers::task_diagnostics;
use publishers::Publishers;

use crate::governor::GovernorDecision;
use crate::mission::{PlanAnswer, PlanForecast, PlanRequest, VehicleStatus};
use crate::record::recorder::QosLevels;
use crate::scheduler::TaskStats;
use crate::task::TaskHealth;
use crate::telemetry::BatteryTelemetry;
use crate::topics::VehicleState;
use crate::topics::{HazardReport, RelativeState, HAZARDS, RELATIVE_STATE};
use nalgebra::Vector3;
use ros2_client::qos::{Durability, History};
pub use ros2_client::{
    Context, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher, QosProfile,
    Subscription,
};
use serde::Serialize;
use std::sync::{mpsc, Arc, Mutex};
use std::thread::JoinHandle;

/// What can go wrong starting the node.
#[derive(Debug, thiserror::Error)]
pub enum Ros2Error {
    #[error(
        "`{0}` is not a ROS 2 name for a vehicle: letters, digits and single underscores, \
         beginning with a letter (e.g. drone_1)"
    )]
    VehicleName(String),
    #[error("cannot start the ROS 2 node: {0}")]
    Start(String),
    #[error("the ROS 2 node's thread could not start: {0}")]
    Thread(#[source] std::io::Error),
}

/// Whether `name` may be one segment of a ROS 2 name.
fn valid_segment(name: &str) -> bool {
    let mut chars = name.chars();
    chars.next().is_some_and(|c| c.is_ascii_alphabetic())
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
        && !name.contains("__")
        && !name.ends_with('_')
}

/// One thing that happened, for the node's thread to publish.
#[derive(Debug)]
pub enum Update {
    Vehicle {
        time_s: f64,
        state: VehicleState,
    },
    Battery(BatteryTelemetry),
    VelocitySetpoint {
        time_s: f64,
        velocity_ned_m_s: Vector3<f64>,
    },
    Phase {
        time_s: f64,
        name: Option<String>,
    },
    Governor(GovernorDecision),
    /// Every task's level, and its statistics so far.
    Tasks {
        time_s: f64,
        levels: QosLevels,
        stats: Vec<TaskStats>,
    },
    Status(VehicleStatus),
    PlanAnswer(PlanAnswer),
    Plan(PlanForecast),
    /// The bus topics the node follows itself.
    Watch(BusWatch),
}

/// The node's own readers of the mission's bus.
pub struct BusWatch {
    relative: crate::bus::Subscriber<RelativeState>,
    hazards: crate::bus::Subscriber<HazardReport>,
}

impl std::fmt::Debug for BusWatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("BusWatch")
    }
}

/// The node, seen from the mission loop.
pub struct Ros2Node {
    updates: Option<mpsc::Sender<Update>>,
    thread: Option<JoinHandle<()>>,
    namespace: String,
    /// Plan changes received, for the runner to take.
    requests: Arc<Mutex<Vec<PlanRequest>>>,
}

/// The topic every vehicle's status goes to, so that a ground station finds the fleet on one.
pub const FLEET_STATUS_TOPIC: (&str, &str) = ("/qosrt/fleet", "status");

/// A vehicle's status on the fleet's topic: the mission at a glance, and whose.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct FleetStatus {
    pub vehicle: String,
    #[serde(flatten)]
    pub status: VehicleStatus,
}

/// How long the mission waits for its node to be ready: a DDS participant that has not come
/// up by then is a named error, not a mission that never starts. 30 s: on a 2-core machine
/// running two other missions at full speed (the fleet test), RustDDS's threads were starved
/// past 15 s in two CI runs of three.
const START_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(30);

/// How long the node's thread waits for the loop before it looks for requests again.
const POLL_PERIOD: std::time::Duration = std::time::Duration::from_millis(10);

impl Ros2Node {
    /// Starts the node `/qosrt/<vehicle>/qosrt` and its publishers; `design_capacity_ah` goes
    /// into every BatteryState.
    pub fn start(vehicle: &str, design_capacity_ah: f64) -> Result<Self, Ros2Error> {
        if !valid_segment(vehicle) {
            return Err(Ros2Error::VehicleName(vehicle.into()));
        }
        let namespace = format!("/qosrt/{vehicle}");
        let (updates, receiver) = mpsc::channel();
        let (started, started_rx) = mpsc::channel();
        let node_namespace = namespace.clone();
        let requests = Arc::new(Mutex::new(Vec::new()));
        let received = requests.clone();
        let vehicle_name = vehicle.to_string();
        let thread = std::thread::Builder::new()
            .name("qosrt-ros2".into())
            .spawn(move || {
                let mut publishers =
                    match Publishers::new(&node_namespace, &vehicle_name, design_capacity_ah) {
                        Ok(publishers) => {
                            let _ = started.send(Ok(()));
                            publishers
                        }
                        Err(error) => {
                            let _ = started.send(Err(error));
                            return;
                        }
                    };
                loop {
                    match receiver.recv_timeout(POLL_PERIOD) {
                        Ok(update) => publishers.publish(update),
                        Err(mpsc::RecvTimeoutError::Timeout) => {}
                        Err(mpsc::RecvTimeoutError::Disconnected) => break,
                    }
                    publishers.follow_bus();
                    let taken = publishers.take_requests();
                    if !taken.is_empty() {
                        lock(&received).extend(taken);
                    }
                }
            })
            .map_err(Ros2Error::Thread)?;
        match started_rx.recv_timeout(START_TIMEOUT) {
            Ok(started) => started?,
            Err(mpsc::RecvTimeoutError::Timeout) => {
                // The thread is left to itself: it holds nothing the mission needs.
                return Err(Ros2Error::Start(format!(
                    "the DDS participant was not ready within {} s",
                    START_TIMEOUT.as_secs()
                )));
            }
            Err(mpsc::RecvTimeoutError::Disconnected) => {
                return Err(Ros2Error::Start("the node's thread ended".into()))
            }
        }
        Ok(Self {
            updates: Some(updates),
            thread: Some(thread),
            namespace,
            requests,
        })
    }

    /// Where the node's topics are (`/qosrt/<vehicle>`).
    pub fn namespace(&self) -> &str {
        &self.namespace
    }

    /// Queues `update` for publishing.
    pub fn send(&self, update: Update) {
        if let Some(updates) = &self.updates {
            // The thread ends only when this side closes: nothing to do if it is gone.
            let _ = updates.send(update);
        }
    }
}

fn lock<T>(mutex: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    // A list of requests is whole whatever panicked while it was held.
    mutex
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The node hears the mission as its other observers do, and publishes it.
impl crate::mission::MissionObserver for Ros2Node {
    fn vehicle(&self, time_s: f64, state: &VehicleState) {
        self.send(Update::Vehicle {
            time_s,
            state: *state,
        });
    }
    fn battery(&self, telemetry: &BatteryTelemetry) {
        self.send(Update::Battery(*telemetry));
    }
    fn velocity_setpoint(&self, time_s: f64, velocity_ned_m_s: &Vector3<f64>) {
        self.send(Update::VelocitySetpoint {
            time_s,
            velocity_ned_m_s: *velocity_ned_m_s,
        });
    }
    fn phase(&self, time_s: f64, phase: Option<&str>) {
        self.send(Update::Phase {
            time_s,
            name: phase.map(str::to_string),
        });
    }
    fn governor(&self, decision: &GovernorDecision) {
        self.send(Update::Governor(decision.clone()));
    }
    fn tasks(&self, time_s: f64, levels: &QosLevels, stats: &[TaskStats]) {
        self.send(Update::Tasks {
            time_s,
            levels: levels.clone(),
            stats: stats.to_vec(),
        });
    }
    fn status(&self, status: &VehicleStatus) {
        self.send(Update::Status(status.clone()));
    }
    fn plan_requests(&self, _now_s: f64) -> Vec<PlanRequest> {
        std::mem::take(&mut *lock(&self.requests))
    }
    fn plan_answer(&self, answer: &PlanAnswer) {
        self.send(Update::PlanAnswer(answer.clone()));
    }
    fn plan(&self, plan: &PlanForecast) {
        self.send(Update::Plan(plan.clone()));
    }
    fn watch_bus(&mut self, bus: &crate::bus::Bus) {
        let watch = bus.subscriber(RELATIVE_STATE).and_then(|relative| {
            Ok(BusWatch {
                relative,
                hazards: bus.subscriber(HAZARDS)?,
            })
        });
        match watch {
            Ok(watch) => self.send(Update::Watch(watch)),
            Err(error) => tracing::warn!(%error, "the ROS 2 node cannot follow the bus"),
        }
    }
}

impl Drop for Ros2Node {
    fn drop(&mut self) {
        self.updates.take();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// A ROS 2 context and a node `namespace/name` in it (a ground station's, a test's).
pub fn open_node(namespace: &str, name: &str) -> Result<(Context, Node), Ros2Error> {
    let start = |e: String| Ros2Error::Start(e);
    let context = Context::new().map_err(|e| start(format!("{e:?}")))?;
    let node = context
        .new_node(
            NodeName::new(namespace, name).map_err(|e| start(format!("{e:?}")))?,
            NodeOptions::new(),
        )
        .map_err(|e| start(format!("{e:?}")))?;
    Ok((context, node))
}

/// `rclcpp::SensorDataQoS`: best effort, volatile, the last five.
pub fn sensor_data_qos() -> QosProfile {
    QosProfile::subscription_default().history(History::KeepLast { depth: 5 })
}

/// State: reliable (a full send window waits 100 ms), the last `depth` kept for subscribers
/// that join later.
pub fn state_qos(depth: usize) -> QosProfile {
    QosProfile::publisher_default()
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth })
}

/// A request and its answer: reliable, not kept for later subscribers (a late answer would
/// answer nobody).
pub fn request_qos() -> QosProfile {
    QosProfile::publisher_default()
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 10 })
}

/// Where a topic is and what it carries: its namespace, name, and `package/type_name`.
pub struct TopicSpec<'a> {
    pub namespace: &'a str,
    pub name: &'a str,
    pub type_name: (&'a str, &'a str),
}

/// Makes the topic and, with it, a reader or a writer (`make`); an error names the topic.
fn with_topic<T>(
    node: &mut Node,
    spec: &TopicSpec,
    qos: QosProfile,
    make: impl FnOnce(
        &mut Node,
        &ros2_client::dds::rustdds::Topic,
        QosProfile,
    ) -> Result<T, ros2_client::CreateError>,
) -> Result<T, Ros2Error> {
    let start =
        |e: String| Ros2Error::Start(format!("topic {}/{}: {e}", spec.namespace, spec.name));
    let name = Name::new(spec.namespace, spec.name).map_err(|e| start(format!("{e:?}")))?;
    let (package, type_name) = spec.type_name;
    let topic = node
        .create_topic(&name, MessageTypeName::new(package, type_name), &qos)
        .map_err(|e| start(format!("{e:?}")))?;
    make(node, &topic, qos).map_err(|e| start(format!("{e:?}")))
}

/// A subscription to `namespace/topic` of `package/type_name`.
pub fn subscription<M: serde::de::DeserializeOwned + 'static>(
    node: &mut Node,
    namespace: &str,
    topic: &str,
    type_name: (&str, &str),
    qos: QosProfile,
) -> Result<Subscription<M>, Ros2Error> {
    let spec = TopicSpec {
        namespace,
        name: topic,
        type_name,
    };
    with_topic(node, &spec, qos, |node, topic, qos| {
        node.create_subscription(topic, Some(qos))
    })
}

/// A publisher on `namespace/topic` of `package/type_name`.
pub fn publisher<M: Serialize>(
    node: &mut Node,
    namespace: &str,
    topic: &str,
    type_name: (&str, &str),
    qos: QosProfile,
) -> Result<Publisher<M>, Ros2Error> {
    let spec = TopicSpec {
        namespace,
        name: topic,
        type_name,
    };
    with_topic(node, &spec, qos, |node, topic, qos| {
        node.create_publisher(topic, Some(qos))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_vehicle_name_that_ros_would_refuse_is_named() {
        for bad in ["", "1drone", "drone-1", "a__b", "drone_", "dr one", "x/y"] {
            assert!(
                matches!(Ros2Node::start(bad, 5.0), Err(Ros2Error::VehicleName(_))),
                "{bad:?}"
            );
        }
        assert!(valid_segment("drone_1") && valid_segment("Vehicle2"));
    }

    /// Nodes started at once, as a companion computer boots several, or a fleet's missions
    /// start together: each comes up. RustDDS 0.11 held its discovery database's lock while
    /// handing a new writer to its event loop, whose queue holds ten; an event loop busy with
    /// the others' discovery then waited on the lock, and the node never finished starting
    /// (one fleet test in three: "the DDS participant was not ready within 30 s").
    #[test]
    fn nodes_started_together_all_come_up() {
        for round in 0..3 {
            let starts: Vec<_> = (0..6)
                .map(|i| {
                    let vehicle = format!("together_{}_{round}_{i}", std::process::id());
                    std::thread::spawn(move || Ros2Node::start(&vehicle, 5.0).map(drop))
                })
                .collect();
            for start in starts {
                start
                    .join()
                    .expect("the starting thread")
                    .expect("the node starts");
            }
        }
    }
}
