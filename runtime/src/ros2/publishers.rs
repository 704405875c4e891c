//! The node's publishing side, on its own thread: what the mission loop queued, as ROS 2
//! messages, and the ground station's plan requests, answered.

use super::messages::{
    self, BatteryState, DiagnosticArray, DiagnosticStatus, Header, KeyValue, StringMessage, Twist,
    TwistStamped,
};
use super::*;

/// The node's publishers, on its own thread.
pub(super) struct Publishers {
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
    vehicle: String,
    fleet_status: Publisher<StringMessage>,
    plan_requests: Subscription<StringMessage>,
    plan_answers: Publisher<StringMessage>,
    plan: Publisher<StringMessage>,
    pad_pose: Publisher<messages::PoseStamped>,
    hazards: Publisher<messages::Detection2DArray>,
    watch: Option<BusWatch>,
    /// The vehicle's last position, for the pad's.
    vehicle_ned_m: Option<Vector3<f64>>,
    /// Each request id taken, and its answer once given: an asker repeats a request until it
    /// hears the answer (DDS drops what is sent before the two sides have met), and a repeat
    /// is answered again, not applied again.
    answers: std::collections::BTreeMap<u64, Option<String>>,
}

impl Publishers {
    pub(super) fn new(
        namespace: &str,
        vehicle: &str,
        design_capacity_ah: f64,
    ) -> Result<Self, Ros2Error> {
        let (context, mut node) = open_node(namespace, "qosrt")?;
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
            fleet_status: publisher(
                &mut node,
                FLEET_STATUS_TOPIC.0,
                FLEET_STATUS_TOPIC.1,
                ("std_msgs", "String"),
                state_qos(1),
            )?,
            plan_requests: subscription(
                &mut node,
                namespace,
                "plan_request",
                ("std_msgs", "String"),
                request_qos(),
            )?,
            plan_answers: publisher(
                &mut node,
                namespace,
                "plan_answer",
                ("std_msgs", "String"),
                request_qos(),
            )?,
            plan: publisher(
                &mut node,
                namespace,
                "plan",
                ("std_msgs", "String"),
                state_qos(1),
            )?,
            pad_pose: publisher(
                &mut node,
                namespace,
                "pad_pose",
                ("geometry_msgs", "PoseStamped"),
                sensor_data_qos(),
            )?,
            hazards: publisher(
                &mut node,
                namespace,
                "hazards",
                ("vision_msgs", "Detection2DArray"),
                sensor_data_qos(),
            )?,
            watch: None,
            vehicle_ned_m: None,
            vehicle: vehicle.into(),
            answers: Default::default(),
            _node: node,
            _context: context,
            design_capacity_ah,
        })
    }

    /// What the bus has new: the pad where the tracker puts it, the hazards.
    pub(super) fn follow_bus(&mut self) {
        let Some(watch) = &mut self.watch else {
            return;
        };
        if let (Some(relative), Some(vehicle)) = (watch.relative.take_new(), self.vehicle_ned_m) {
            let estimate = &relative.value.estimate;
            let pose = messages::pad_pose(estimate.time_s, &vehicle, &estimate.uav_relative_ned_m);
            let _ = self.pad_pose.publish(pose);
        }
        if let Some(report) = watch.hazards.take_new() {
            let _ = self
                .hazards
                .publish(messages::hazard_detections(&report.value));
        }
    }

    /// The plan changes received since the last look; one that is not a request (malformed
    /// CDR, or JSON that is not a [`PlanRequest`]) is answered with why (its id 0, as it has
    /// none that can be read), and the mission goes on.
    pub(super) fn take_requests(&mut self) -> Vec<PlanRequest> {
        let mut requests = Vec::new();
        loop {
            let data = match self.plan_requests.take() {
                Ok(Some((message, _))) => message.data,
                Ok(None) => break,
                // RustDDS has taken the sample that failed: the next one follows.
                Err(error) => {
                    self.refuse(format!("not a std_msgs/String (malformed CDR: {error:?})"));
                    continue;
                }
            };
            match serde_json::from_str::<PlanRequest>(&data) {
                Ok(request) => match self.answers.get(&request.id) {
                    None => {
                        self.answers.insert(request.id, None);
                        requests.push(request);
                    }
                    Some(Some(answer)) => {
                        let _ = self.plan_answers.publish(StringMessage {
                            data: answer.clone(),
                        });
                    }
                    // Taken, not yet answered: the answer is on its way.
                    Some(None) => {}
                },
                Err(error) => self.refuse(format!(
                    "not a plan request ({error}): expected {{\"id\": N, \"reserve_fraction\": F, \
                     \"time_left_s\": S, \"levels\": {{\"TASK\": {{\"min\": A, \"max\": B}}}}}} \
                     (each change optional)"
                )),
            }
        }
        requests
    }

    /// Answers something that is not a plan request with why.
    fn refuse(&mut self, refusal: String) {
        tracing::warn!(%refusal, "a plan request was refused");
        let answer = PlanRefusal {
            id: 0,
            accepted: false,
            refusal,
        };
        let _ = self.plan_answers.publish(StringMessage {
            data: json(&answer),
        });
    }

    pub(super) fn publish(&mut self, update: Update) {
        let result = match update {
            Update::Vehicle { time_s, state } => {
                self.vehicle_ned_m = state.position_ned_m.or(self.vehicle_ned_m);
                match messages::vehicle_pose(time_s, &state) {
                    Some(pose) => self.pose.publish(pose).map_err(|e| format!("{e:?}")),
                    None => Ok(()),
                }
            }
            Update::Plan(plan) => self
                .plan
                .publish(StringMessage { data: json(&plan) })
                .map_err(|e| format!("{e:?}")),
            Update::Watch(watch) => {
                self.watch = Some(watch);
                Ok(())
            }
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
            Update::Status(status) => self
                .fleet_status
                .publish(StringMessage {
                    data: json(&FleetStatus {
                        vehicle: self.vehicle.clone(),
                        status,
                    }),
                })
                .map_err(|e| format!("{e:?}")),
            Update::PlanAnswer(answer) => {
                let data = json(&answer);
                self.answers.insert(answer.id, Some(data.clone()));
                self.plan_answers
                    .publish(StringMessage { data })
                    .map_err(|e| format!("{e:?}"))
            }
        };
        if let Err(error) = result {
            tracing::debug!(%error, "a ROS 2 message was not published");
        }
    }
}

/// A refusal of something that was not a plan request at all.
#[derive(Serialize)]
struct PlanRefusal {
    id: u64,
    accepted: bool,
    refusal: String,
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
