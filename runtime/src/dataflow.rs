//! Who feeds whom: the task graph a config makes, from each plugin's declared ports
//! ([`crate::catalog::PluginInfo`]) and what the mission itself publishes and reads
//! ([`MISSION_INPUTS`], [`MISSION_OUTPUTS`]). Pure: the config check rejects a task whose input
//! nobody produces from it, and `qosrt check --graph` prints it as text or Graphviz.

use crate::catalog::{PluginCatalog, Port, MISSION_INPUTS, MISSION_OUTPUTS};
use crate::config::MissionConfig;
use std::fmt::Write;

/// One end of an edge: the mission (the autopilot, the camera, the runner) or a task.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Endpoint {
    Mission(&'static str),
    /// Index into the config's tasks.
    Task(usize),
}

/// Messages on `topic` flow from `from` to `to`.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct Edge {
    pub from: Endpoint,
    pub to: Endpoint,
    pub topic: &'static str,
    pub message: &'static str,
}

/// An input of a task that nothing in the mission publishes.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct Unfed {
    /// Index into the config's tasks.
    pub task: usize,
    pub port: Port,
    /// The catalogue's plugins that publish the topic.
    pub producers: Vec<&'static str>,
}

#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TaskGraph {
    /// The tasks' names, in config order.
    pub tasks: Vec<String>,
    /// Each task's plugin, as the config names it.
    pub plugins: Vec<String>,
    pub edges: Vec<Edge>,
    /// Inputs nobody publishes, optional ones included (see [`Port::optional`]).
    pub unfed: Vec<Unfed>,
    /// Outputs nobody in the mission reads (a recording still keeps them): (task, port).
    pub unread: Vec<(usize, Port)>,
}

impl TaskGraph {
    /// The inputs a task cannot work without that nobody publishes.
    pub fn missing_inputs(&self) -> impl Iterator<Item = &Unfed> {
        self.unfed.iter().filter(|unfed| !unfed.port.optional)
    }
}

/// The graph of `config`'s tasks. A task whose plugin the catalogue does not know has no ports
/// (the config check reports the plugin itself).
pub fn task_graph(config: &MissionConfig, catalog: &PluginCatalog) -> TaskGraph {
    let ports: Vec<(&[Port], &[Port])> = config
        .tasks
        .iter()
        .map(|task| {
            catalog
                .get(&task.plugin)
                .map_or((&[][..], &[][..]), |info| (info.inputs, info.outputs))
        })
        .collect();
    let mut edges = Vec::new();
    let mut unfed = Vec::new();
    for (task, (inputs, _)) in ports.iter().enumerate() {
        for input in *inputs {
            let from_mission = MISSION_INPUTS
                .iter()
                .filter(|source| source.port.topic == input.topic)
                .map(|source| Endpoint::Mission(source.endpoint));
            let from_tasks = ports
                .iter()
                .enumerate()
                .filter(|&(other, (_, outputs))| {
                    other != task && outputs.iter().any(|output| output.topic == input.topic)
                })
                .map(|(other, _)| Endpoint::Task(other));
            let before = edges.len();
            edges.extend(from_mission.chain(from_tasks).map(|from| Edge {
                from,
                to: Endpoint::Task(task),
                topic: input.topic,
                message: input.message,
            }));
            if edges.len() == before {
                unfed.push(Unfed {
                    task,
                    port: *input,
                    producers: catalog.producers_of(input.topic).collect(),
                });
            }
        }
    }
    let mut unread = Vec::new();
    for (task, (_, outputs)) in ports.iter().enumerate() {
        for output in *outputs {
            let read = edges
                .iter()
                .any(|edge| edge.from == Endpoint::Task(task) && edge.topic == output.topic);
            let before = edges.len();
            edges.extend(
                MISSION_OUTPUTS
                    .iter()
                    .filter(|sink| sink.port.topic == output.topic)
                    .map(|sink| Edge {
                        from: Endpoint::Task(task),
                        to: Endpoint::Mission(sink.endpoint),
                        topic: output.topic,
                        message: output.message,
                    }),
            );
            if !read && edges.len() == before {
                unread.push((task, *output));
            }
        }
    }
    TaskGraph {
        tasks: config.tasks.iter().map(|task| task.name.clone()).collect(),
        plugins: config
            .tasks
            .iter()
            .map(|task| task.plugin.clone())
            .collect(),
        edges,
        unfed,
        unread,
    }
}

impl TaskGraph {
    fn name(&self, endpoint: Endpoint) -> &str {
        match endpoint {
            Endpoint::Mission(name) => name,
            Endpoint::Task(index) => &self.tasks[index],
        }
    }

    /// For a person: each task with what it reads (and from whom) and what it writes (and for
    /// whom).
    pub fn render_text(&self) -> String {
        let mut text = String::new();
        for (index, (task, plugin)) in self.tasks.iter().zip(&self.plugins).enumerate() {
            let _ = writeln!(text, "{task} ({plugin})");
            let here = Endpoint::Task(index);
            for (topic, message, others) in self.grouped(|edge| edge.to == here, |e| e.from) {
                let _ = writeln!(text, "  reads  {topic} ({message}) ← {others}");
            }
            for unfed in self.unfed.iter().filter(|unfed| unfed.task == index) {
                let what = if unfed.port.optional {
                    "optional; nothing publishes it"
                } else {
                    "NOTHING PUBLISHES IT"
                };
                let _ = writeln!(
                    text,
                    "  reads  {} ({}) ← {what}",
                    unfed.port.topic, unfed.port.message
                );
            }
            for (topic, message, others) in self.grouped(|edge| edge.from == here, |e| e.to) {
                let _ = writeln!(text, "  writes {topic} ({message}) → {others}");
            }
            for (_, port) in self.unread.iter().filter(|(task, _)| *task == index) {
                let _ = writeln!(
                    text,
                    "  writes {} ({}) → nobody reads it",
                    port.topic, port.message
                );
            }
        }
        text
    }

    /// The edges `select` picks, one line per topic, with the other ends joined.
    fn grouped(
        &self,
        select: impl Fn(&Edge) -> bool,
        other_end: impl Fn(&Edge) -> Endpoint,
    ) -> Vec<(&'static str, &'static str, String)> {
        let mut lines: Vec<(&'static str, &'static str, Vec<&str>)> = Vec::new();
        for edge in self.edges.iter().filter(|edge| select(edge)) {
            let other = self.name(other_end(edge));
            match lines.iter_mut().find(|(topic, _, _)| *topic == edge.topic) {
                Some((_, _, others)) => others.push(other),
                None => lines.push((edge.topic, edge.message, vec![other])),
            }
        }
        lines
            .into_iter()
            .map(|(topic, message, others)| (topic, message, others.join(", ")))
            .collect()
    }

    /// Graphviz: `qosrt check --graph dot | dot -Tsvg > graph.svg`. Tasks are boxes, the
    /// mission's ends ellipses, an unfed input a red dashed edge from "nothing".
    pub fn render_dot(&self, title: &str) -> String {
        let mut dot = String::new();
        let _ = writeln!(dot, "digraph {} {{", quoted(title));
        dot.push_str("  rankdir=LR;\n  node [shape=box, style=rounded];\n");
        let mut mission_ends: Vec<&str> = Vec::new();
        for edge in &self.edges {
            for end in [edge.from, edge.to] {
                if let Endpoint::Mission(name) = end {
                    if !mission_ends.contains(&name) {
                        mission_ends.push(name);
                    }
                }
            }
        }
        for end in &mission_ends {
            let _ = writeln!(
                dot,
                "  {} [shape=ellipse];",
                quoted(&format!("mission:{end}"))
            );
        }
        for (index, (task, plugin)) in self.tasks.iter().zip(&self.plugins).enumerate() {
            let _ = writeln!(
                dot,
                "  {} [label={}];",
                quoted(&node_id(self, Endpoint::Task(index))),
                quoted(&format!("{task}\n{plugin}"))
            );
        }
        for edge in &self.edges {
            let _ = writeln!(
                dot,
                "  {} -> {} [label={}];",
                quoted(&node_id(self, edge.from)),
                quoted(&node_id(self, edge.to)),
                quoted(edge.topic)
            );
        }
        if self.unfed.iter().any(|unfed| !unfed.port.optional) {
            dot.push_str("  \"nothing\" [shape=plaintext, fontcolor=red];\n");
        }
        for unfed in self.missing_inputs() {
            let _ = writeln!(
                dot,
                "  \"nothing\" -> {} [label={}, color=red, style=dashed];",
                quoted(&node_id(self, Endpoint::Task(unfed.task))),
                quoted(unfed.port.topic)
            );
        }
        dot.push_str("}\n");
        dot
    }
}

fn node_id(graph: &TaskGraph, endpoint: Endpoint) -> String {
    match endpoint {
        Endpoint::Mission(name) => format!("mission:{name}"),
        Endpoint::Task(_) => format!("task:{}", graph.name(endpoint)),
    }
}

/// A Graphviz double-quoted string.
fn quoted(text: &str) -> String {
    let escaped = text
        .replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n");
    format!("\"{escaped}\"")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::load_str;

    const REFERENCE: &str = include_str!("../../qos.toml");

    fn reference_graph() -> TaskGraph {
        let catalog = PluginCatalog::builtin();
        let config = load_str(REFERENCE, None, &catalog).expect("the reference mission loads");
        task_graph(&config, &catalog)
    }

    fn edge(graph: &TaskGraph, from: &str, to: &str, topic: &str) -> bool {
        graph
            .edges
            .iter()
            .any(|e| graph.name(e.from) == from && graph.name(e.to) == to && e.topic == topic)
    }

    /// The reference mission's chain, written out by hand from the plugins' documented inputs
    /// and outputs: camera → detection → tracking → landing → autopilot, the hazard task beside.
    #[test]
    fn the_reference_mission_is_the_landing_chain_with_the_hazard_task_beside_it() {
        let graph = reference_graph();
        assert_eq!(graph.tasks, ["detection", "tracking", "landing", "hazard"]);
        let expected = [
            ("camera", "detection", "camera/frame"),
            ("detection", "tracking", "vision/landing_marker"),
            ("autopilot", "tracking", "vehicle/state"),
            ("tracking", "landing", "tracking/relative_state"),
            ("autopilot", "landing", "vehicle/state"),
            ("mission", "landing", "mission/phase"),
            ("landing", "autopilot", "landing/setpoint"),
            ("tracking", "mission", "tracking/relative_state"),
            ("camera", "hazard", "camera/frame"),
            ("autopilot", "hazard", "vehicle/state"),
            ("tracking", "hazard", "tracking/relative_state"),
        ];
        for (from, to, topic) in expected {
            assert!(edge(&graph, from, to, topic), "{from} → {to} on {topic}");
        }
        assert_eq!(graph.edges.len(), expected.len(), "{:#?}", graph.edges);
        assert!(graph.unfed.is_empty(), "{:?}", graph.unfed);
        assert_eq!(graph.unread.len(), 1, "only the hazard reports go unread");
    }

    #[test]
    fn a_task_without_its_producer_is_unfed_and_the_plugins_that_could_feed_it_are_named() {
        let catalog = PluginCatalog::builtin();
        let mut config = load_str(REFERENCE, None, &catalog).unwrap();
        config.tasks.retain(|task| task.name != "tracking");
        let graph = task_graph(&config, &catalog);
        let missing: Vec<_> = graph.missing_inputs().collect();
        assert_eq!(missing.len(), 1, "{missing:?}");
        assert_eq!(graph.tasks[missing[0].task], "landing");
        assert_eq!(missing[0].port.topic, "tracking/relative_state");
        assert_eq!(missing[0].producers, ["kalman_tracker", "hybrid_tracking"]);
        // The hazard task reads the tracker's estimate too, but works without it.
        let optional: Vec<_> = graph.unfed.iter().filter(|u| u.port.optional).collect();
        assert_eq!(optional.len(), 1);
        assert_eq!(graph.tasks[optional[0].task], "hazard");
        let text = graph.render_text();
        assert!(
            text.contains("reads  tracking/relative_state (RelativeState) ← NOTHING PUBLISHES IT"),
            "{text}"
        );
    }

    #[test]
    fn the_text_names_each_tasks_readers_and_writers() {
        let text = reference_graph().render_text();
        assert!(text.starts_with("detection (landing_marker)\n"), "{text}");
        assert!(
            text.contains(
                "  writes tracking/relative_state (RelativeState) → landing, hazard, mission\n"
            ),
            "{text}"
        );
        assert!(
            text.contains("  reads  vehicle/state (VehicleState) ← autopilot\n"),
            "{text}"
        );
        assert!(
            text.ends_with("  writes vision/hazards (HazardReport) → nobody reads it\n"),
            "{text}"
        );
    }

    /// The dot output parsed back line by line: every edge of the graph is there once, between
    /// declared nodes, and quotes in a name cannot break out of its string.
    #[test]
    fn the_dot_output_has_every_edge_between_declared_nodes() {
        let graph = reference_graph();
        let dot = graph.render_dot("say \"hi\"");
        assert!(dot.starts_with("digraph \"say \\\"hi\\\"\" {\n"), "{dot}");
        assert!(dot.ends_with("}\n"));
        let nodes: Vec<&str> = dot
            .lines()
            .filter(|line| line.contains(" [") && !line.contains("->") && line.starts_with("  \""))
            .map(|line| line.trim().split(" [").next().unwrap())
            .collect();
        let arrows: Vec<(&str, &str)> = dot
            .lines()
            .filter_map(|line| {
                let (from, rest) = line.trim().split_once(" -> ")?;
                Some((from, rest.split(" [").next()?))
            })
            .collect();
        assert_eq!(arrows.len(), graph.edges.len());
        for (from, to) in &arrows {
            assert!(
                nodes.contains(from) && nodes.contains(to),
                "{from} -> {to}\n{dot}"
            );
        }
        assert!(dot.contains("\"mission:camera\" -> \"task:detection\" [label=\"camera/frame\"];"));
    }
}
