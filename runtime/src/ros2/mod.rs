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

use crate::governor::GovernorDecision;
use crate::record::recorder::QosLevels;
use crate::scheduler::TaskStats;
use crate::task::TaskHealth;
use crate::telemetry::BatteryTelemetry;
use crate::topics::VehicleState;
use messages::{
    BatteryState, DiagnosticArray, DiagnosticStatus, Header, KeyValue, StringMessage, Twist,
    TwistStamped,
};
use nalgebra::Vector3;
use ros2_client::rustdds::policy::{Durability, History, Reliability};
use ros2_client::rustdds::{Duration as DdsDuration, QosPolicies, QosPolicyBuilder};
use ros2_client::{Context, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher};
use serde::Serialize;
use std::sync::mpsc;
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
#[derive(Debug, Clone)]
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
}

/// The node, seen from the mission loop.
pub struct Ros2Node {
    updates: Option<mpsc::Sender<Update>>,
    thread: Option<JoinHandle<()>>,
    namespace: String,
}

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
        let thread = std::thread::Builder::new()
            .name("qosrt-ros2".into())
            .spawn(move || {
                let publishers = match Publishers::new(&node_namespace, design_capacity_ah) {
                    Ok(publishers) => {
                        let _ = started.send(Ok(()));
                        publishers
                    }
                    Err(error) => {
                        let _ = started.send(Err(error));
                        return;
                    }
                };
                for update in receiver {
                    publishers.publish(update);
                }
            })
            .map_err(Ros2Error::Thread)?;
        started_rx
            .recv()
            .map_err(|_| Ros2Error::Start("the node's thread ended".into()))??;
        Ok(Self {
            updates: Some(updates),
            thread: Some(thread),
            namespace,
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
}

impl Drop for Ros2Node {
    fn drop(&mut self) {
        self.updates.take();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// `rclcpp::SensorDataQoS`: best effort, volatile, the last five.
fn sensor_data_qos() -> QosPolicies {
    QosPolicyBuilder::new()
        .reliability(Reliability::BestEffort)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 5 })
        .build()
}

/// State: reliable, the last `depth` kept for subscribers that join later.
fn state_qos(depth: i32) -> QosPolicies {
    QosPolicyBuilder::new()
        .reliability(Reliability::Reliable {
            max_blocking_time: DdsDuration::from_millis(100),
        })
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth })
        .build()
}

/// The node's publishers, on its own thread.
struct Publishers {
    // The node owns the DDS participant the publishers write through.
    _node: Node,
    _context: Context,
    design_capacity_ah: f64,
    pose: Publisher<messages::PoseStamped>,
    battery: Publisher<BatteryState>,
    setpoint: Publisher<TwistStamped>,
    phase: Publisher<StringMessage>,
    governor: Publisher<StringMessage>,
    diagnostics: Publisher<DiagnosticArray>,
}

impl Publishers {
    fn new(namespace: &str, design_capacity_ah: f64) -> Result<Self, Ros2Error> {
        let start = |e: &dyn std::fmt::Display| Ros2Error::Start(e.to_string());
        let context = Context::new().map_err(|e| start(&format!("{e:?}")))?;
        let mut node = context
            .new_node(
                NodeName::new(namespace, "qosrt").map_err(|e| start(&format!("{e:?}")))?,
                NodeOptions::new(),
            )
            .map_err(|e| start(&format!("{e:?}")))?;
        Ok(Self {
            pose: publisher(
                &mut node,
                namespace,
                "pose",
                ("geometry_msgs", "PoseStamped"),
                sensor_data_qos(),
            )?,
            battery: publisher(
                &mut node,
                namespace,
                "battery",
                ("sensor_msgs", "BatteryState"),
                sensor_data_qos(),
            )?,
            setpoint: publisher(
                &mut node,
                namespace,
                "velocity_setpoint",
                ("geometry_msgs", "TwistStamped"),
                sensor_data_qos(),
            )?,
            phase: publisher(
                &mut node,
                namespace,
                "phase",
                ("std_msgs", "String"),
                state_qos(1),
            )?,
            governor: publisher(
                &mut node,
                namespace,
                "governor",
                ("std_msgs", "String"),
                state_qos(20),
            )?,
            diagnostics: publisher(
                &mut node,
                namespace,
                "diagnostics",
                ("diagnostic_msgs", "DiagnosticArray"),
                state_qos(1),
            )?,
            _node: node,
            _context: context,
            design_capacity_ah,
        })
    }

    fn publish(&self, update: Update) {
        let result = match update {
            Update::Vehicle { time_s, state } => match messages::vehicle_pose(time_s, &state) {
                Some(pose) => self.pose.publish(pose).map_err(|e| format!("{e:?}")),
                None => Ok(()),
            },
            Update::Battery(telemetry) => self
                .battery
                .publish(BatteryState::from_telemetry(
                    &telemetry,
                    self.design_capacity_ah,
                ))
                .map_err(|e| format!("{e:?}")),
            Update::VelocitySetpoint {
                time_s,
                velocity_ned_m_s,
            } => self
                .setpoint
                .publish(TwistStamped {
                    header: Header::at(time_s, "map"),
                    twist: Twist {
                        linear: messages::enu(&velocity_ned_m_s),
                        ..Twist::default()
                    },
                })
                .map_err(|e| format!("{e:?}")),
            Update::Phase { time_s, name } => self
                .phase
                .publish(StringMessage {
                    data: json(&PhaseRecord {
                        time_s,
                        phase: name,
                    }),
                })
                .map_err(|e| format!("{e:?}")),
            Update::Governor(decision) => self
                .governor
                .publish(StringMessage {
                    data: json(&decision),
                })
                .map_err(|e| format!("{e:?}")),
            Update::Tasks {
                time_s,
                levels,
                stats,
            } => self
                .diagnostics
                .publish(task_diagnostics(time_s, &levels, &stats))
                .map_err(|e| format!("{e:?}")),
        };
        if let Err(error) = result {
            tracing::debug!(%error, "a ROS 2 message was not published");
        }
    }
}

fn publisher<M: Serialize>(
    node: &mut Node,
    namespace: &str,
    topic: &str,
    (package, type_name): (&str, &str),
    qos: QosPolicies,
) -> Result<Publisher<M>, Ros2Error> {
    let start = |e: String| Ros2Error::Start(format!("topic {namespace}/{topic}: {e}"));
    let name = Name::new(namespace, topic).map_err(|e| start(format!("{e:?}")))?;
    let topic = node
        .create_topic(&name, MessageTypeName::new(package, type_name), &qos)
        .map_err(|e| start(format!("{e:?}")))?;
    node.create_publisher(&topic, Some(qos))
        .map_err(|e| start(format!("{e:?}")))
}

/// The phase as its topic carries it.
#[derive(Serialize)]
struct PhaseRecord {
    time_s: f64,
    /// `None` before the first phase and after the last.
    phase: Option<String>,
}

fn json<T: Serialize>(value: &T) -> String {
    serde_json::to_string(value).expect("the runtime's records serialise")
}

/// Each task's level and statistics as one `DiagnosticStatus` (its `name` the task's).
pub fn task_diagnostics(time_s: f64, levels: &QosLevels, stats: &[TaskStats]) -> DiagnosticArray {
    let status = levels
        .tasks
        .iter()
        .map(|(task, level)| {
            let mut values = vec![
                KeyValue {
                    key: "level".into(),
                    value: level.level.to_string(),
                },
                KeyValue {
                    key: "value".into(),
                    value: level.value.to_string(),
                },
            ];
            let task_stats = stats.iter().find(|s| s.name == *task);
            if let Some(s) = task_stats {
                let counts = [
                    ("period_ms", s.period_ms.to_string()),
                    ("activations", s.activations.to_string()),
                    ("overruns", s.overruns.to_string()),
                    ("skipped", s.skipped.to_string()),
                    ("failures", s.failures.to_string()),
                ];
                values.extend(counts.map(|(key, value)| KeyValue {
                    key: key.into(),
                    value,
                }));
            }
            // OK while it runs, WARN while it restarts, ERROR once it has failed for good.
            let health = task_stats.map_or(TaskHealth::Running, |s| s.health);
            DiagnosticStatus {
                level: match health {
                    TaskHealth::Running => 0,
                    TaskHealth::Restarting => 1,
                    TaskHealth::Failed => 2,
                },
                name: format!("qosrt/{task}"),
                message: match health {
                    TaskHealth::Running => format!("level {}", level.level),
                    other => format!(
                        "{other}: {}",
                        task_stats
                            .and_then(|s| s.last_error.clone())
                            .unwrap_or_default()
                    ),
                },
                hardware_id: String::new(),
                values,
            }
        })
        .collect();
    DiagnosticArray {
        header: Header::at(time_s, ""),
        status,
    }
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
}
