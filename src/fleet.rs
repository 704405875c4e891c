//! `qosrt fleet`: the ground station's view of every vehicle flying with `--ros2`, found on
//! the fleet's status topic (no list of vehicles to keep), and `qosrt fleet set` to change a
//! vehicle's plan in flight.

use runtime::mission::{PlanAnswer, PlanRequest};
use runtime::ros2::messages::StringMessage;
use runtime::ros2::{
    open_node, publisher, request_qos, state_qos, subscription, FleetStatus, Ros2Error,
    FLEET_STATUS_TOPIC,
};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::{IsTerminal, Write};
use std::process::ExitCode;
use std::time::{Duration, Instant};

/// Exit status when the vehicle refused the change.
const EXIT_REFUSED: u8 = 3;
/// Exit status when no answer came (an unknown vehicle, no network).
const EXIT_NO_ANSWER: u8 = 4;

/// `qosrt fleet`'s arguments.
#[derive(clap::Args)]
pub struct FleetArgs {
    #[command(subcommand)]
    pub action: Option<FleetAction>,
    /// Print one JSON snapshot of the fleet per period, one per line, for scripts.
    #[arg(long)]
    pub json: bool,
    /// Seconds between snapshots.
    #[arg(long, value_name = "S", default_value_t = 1.0)]
    pub period_s: f64,
    /// Stop after this many seconds (default: until interrupted).
    #[arg(long, value_name = "S")]
    pub duration_s: Option<f64>,
}

#[derive(clap::Subcommand)]
pub enum FleetAction {
    /// Change a vehicle's plan in flight: `qosrt fleet set drone_1 reserve=0.3
    /// time_left_s=600 hazard=1..3`. `reserve` is a fraction of the full pack's usable energy;
    /// `time_left_s` the rest of the mission from now (tracking takes what transit and landing
    /// leave); `TASK=MIN..MAX`, `TASK=N` or `TASK=all` the levels a task may run at. The
    /// vehicle applies them together and re-plans at once, answering with its levels and
    /// margin, or refuses them together and says why.
    Set {
        vehicle: String,
        #[arg(value_name = "KEY=VALUE", required = true, value_parser = parse_change)]
        changes: Vec<String>,
        /// How long to wait for the answer (finding the vehicle on the network takes up to
        /// RustDDS's 10 s announcement period).
        #[arg(long, value_name = "S", default_value_t = 25.0)]
        timeout_s: f64,
        /// Print the answer as JSON.
        #[arg(long)]
        json: bool,
    },
}

/// One change `qosrt fleet set` asks for, as written (`reserve=0.3`), checked.
fn parse_change(text: &str) -> Result<String, String> {
    PlanRequest::default().add_change(text)?;
    Ok(text.to_string())
}

/// The request that asks for `changes`, numbered `id`.
fn request(id: u64, changes: &[String]) -> PlanRequest {
    let mut request = PlanRequest {
        id,
        ..PlanRequest::default()
    };
    for change in changes {
        // Checked when the arguments were parsed.
        let _ = request.add_change(change);
    }
    request
}

pub fn run(args: &FleetArgs) -> ExitCode {
    let result = match &args.action {
        None => view(args),
        Some(FleetAction::Set {
            vehicle,
            changes,
            timeout_s,
            json,
        }) => return set(vehicle, changes, *timeout_s, *json),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("error: {error}");
            ExitCode::FAILURE
        }
    }
}

/// One vehicle as the fleet sees it.
#[derive(Serialize)]
struct Seen<'a> {
    /// Seconds since its last status.
    link_age_s: f64,
    #[serde(flatten)]
    status: &'a FleetStatus,
}

/// The fleet's view, refreshed every period.
fn view(args: &FleetArgs) -> Result<(), Ros2Error> {
    let (_context, mut node) = open_node("/qosrt", "fleet")?;
    let statuses = subscription::<StringMessage>(
        &mut node,
        FLEET_STATUS_TOPIC.0,
        FLEET_STATUS_TOPIC.1,
        ("std_msgs", "String"),
        state_qos(100),
    )?;
    let started = Instant::now();
    let mut fleet: BTreeMap<String, (FleetStatus, Instant)> = BTreeMap::new();
    let mut next = started + Duration::from_secs_f64(args.period_s);
    let terminal = !args.json && std::io::stdout().is_terminal();
    loop {
        while let Ok(Some((message, _))) = statuses.take() {
            match serde_json::from_str::<FleetStatus>(&message.data) {
                // A reader that joins late is handed a vehicle's kept statuses oldest first:
                // only a newer one replaces what is shown.
                Ok(status) => match fleet.get(&status.vehicle) {
                    Some((shown, _)) if shown.status.time_s > status.status.time_s => {}
                    _ => {
                        fleet.insert(status.vehicle.clone(), (status, Instant::now()));
                    }
                },
                Err(error) => tracing::warn!(%error, "a fleet status that is not one was ignored"),
            }
        }
        let now = Instant::now();
        if now >= next {
            next += Duration::from_secs_f64(args.period_s);
            let seen: Vec<Seen> = fleet
                .values()
                .map(|(status, at)| Seen {
                    link_age_s: now.duration_since(*at).as_secs_f64(),
                    status,
                })
                .collect();
            if args.json {
                let snapshot = serde_json::json!({
                    "time_s": now.duration_since(started).as_secs_f64(),
                    "vehicles": seen,
                });
                // A reader that went away (a closed pipe) ends the view, not a panic.
                if writeln!(std::io::stdout(), "{snapshot}").is_err() {
                    return Ok(());
                }
            } else {
                print_table(&seen, terminal);
            }
        }
        if args
            .duration_s
            .is_some_and(|limit| now.duration_since(started).as_secs_f64() >= limit)
        {
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The fleet as a table; a vehicle whose margin is negative (or that was told to land) is
/// marked with `!`.
fn print_table(seen: &[Seen], terminal: bool) {
    if terminal {
        // Clear the screen and go home: the table stays in place as it refreshes.
        print!("\x1b[2J\x1b[H");
    }
    println!(
        "{:<2}{:<14} {:<10} {:>8} {:>10} {:>10} {:>10} {:>8} {:>7}  {:<28} last event",
        "",
        "vehicle",
        "phase",
        "battery",
        "margin",
        "can fly",
        "mission",
        "reserve",
        "link",
        "levels",
    );
    for vehicle in seen {
        let status = &vehicle.status.status;
        let warning = status.land_now || status.margin_wh.is_some_and(|m| m < 0.0);
        let or_dash = |value: Option<String>| value.unwrap_or_else(|| "—".into());
        let levels: Vec<String> = status
            .levels
            .iter()
            .map(|(task, level)| format!("{task}={level}"))
            .collect();
        println!(
            "{:<2}{:<14} {:<10} {:>8} {:>10} {:>10} {:>10} {:>8} {:>6.1}s  {:<28} {}",
            if warning { "!" } else { "" },
            vehicle.status.vehicle,
            status.phase.as_deref().unwrap_or("—"),
            or_dash(
                status
                    .battery_fraction
                    .map(|f| format!("{:.0} %", f * 100.0))
            ),
            or_dash(status.margin_wh.map(|m| format!("{m:+.1} Wh"))),
            or_dash(status.flight_time_left_s.map(|s| format!("{:.0} s", s))),
            or_dash(status.mission_time_left_s.map(|s| format!("{:.0} s", s))),
            format!("{:.2}", status.reserve_fraction),
            vehicle.link_age_s,
            levels.join(" "),
            status.last_event.as_deref().unwrap_or(""),
        );
    }
    if seen.is_empty() {
        println!(
            "no vehicle heard yet on {}/{}",
            FLEET_STATUS_TOPIC.0, FLEET_STATUS_TOPIC.1
        );
    }
}

/// Asks `vehicle` for `changes` and prints its answer.
fn set(vehicle: &str, changes: &[String], timeout_s: f64, json: bool) -> ExitCode {
    match ask(vehicle, changes, timeout_s) {
        Ok(Some(asked)) => {
            let answer = &asked.answer;
            if json {
                println!("{}", serde_json::to_string(&asked).unwrap_or_default());
            } else if answer.accepted {
                let levels: Vec<String> = answer
                    .levels
                    .tasks
                    .iter()
                    .map(|(task, level)| format!("{task}={}", level.level))
                    .collect();
                let bounds: Vec<String> = answer
                    .allowed_levels
                    .iter()
                    .map(|(task, range)| format!("{task} in {}..={}", range.min, range.max))
                    .collect();
                println!(
                    "{vehicle}: reserve {:.2}, time left {}, margin {}, levels {}{}{} \
                     (found in {:.1} s, answered {:.0} ms after the ask)",
                    answer.reserve_fraction,
                    answer
                        .time_left_s
                        .map_or("—".into(), |s| format!("{s:.0} s")),
                    answer
                        .margin_wh
                        .map_or("—".into(), |m| format!("{m:+.2} Wh")),
                    levels.join(" "),
                    if bounds.is_empty() {
                        String::new()
                    } else {
                        format!(" ({})", bounds.join(", "))
                    },
                    if answer.land_now {
                        "; landing: the battery cannot finish the mission"
                    } else {
                        ""
                    },
                    asked.found_s,
                    asked.answered_ms
                );
            } else {
                eprintln!(
                    "error: {vehicle} refused: {}",
                    answer.refusal.as_deref().unwrap_or("no reason given")
                );
            }
            if answer.accepted {
                ExitCode::SUCCESS
            } else {
                ExitCode::from(EXIT_REFUSED)
            }
        }
        Ok(None) => {
            eprintln!(
                "error: no answer from `{vehicle}` within {timeout_s} s: no vehicle of that name \
                 flies with --ros2 on this network (qosrt fleet lists those that do)"
            );
            ExitCode::from(EXIT_NO_ANSWER)
        }
        Err(error) => {
            eprintln!("error: {error}");
            ExitCode::FAILURE
        }
    }
}

/// A vehicle's answer, with how long it took.
#[derive(Serialize)]
struct Asked {
    #[serde(flatten)]
    answer: PlanAnswer,
    /// From the start until the vehicle's request reader and answer writer were matched (the
    /// DDS discovery of the two sides).
    found_s: f64,
    /// From the first ask after that until the answer arrived: the re-plan's round trip.
    answered_ms: f64,
}

/// Finds the vehicle's request and answer topics, then asks until it answers (a request sent
/// before the reliable writer has met its reader could be lost, so it is repeated; the vehicle
/// answers a repeat without applying it again).
fn ask(vehicle: &str, changes: &[String], timeout_s: f64) -> Result<Option<Asked>, Ros2Error> {
    let namespace = format!("/qosrt/{vehicle}");
    let (_context, mut node) = open_node("/qosrt", "fleet_set")?;
    let requests = publisher::<StringMessage>(
        &mut node,
        &namespace,
        "plan_request",
        ("std_msgs", "String"),
        request_qos(),
    )?;
    let answers = subscription::<StringMessage>(
        &mut node,
        &namespace,
        "plan_answer",
        ("std_msgs", "String"),
        request_qos(),
    )?;
    // The node's spinner follows the discovery, so the matched peers can be counted.
    let spinner = node
        .spinner()
        .map_err(|e| Ros2Error::Start(format!("{e:?}")))?;
    std::thread::Builder::new()
        .name("qosrt-fleet-spin".into())
        .spawn(move || {
            let _ = futures::executor::block_on(spinner.spin());
        })
        .map_err(Ros2Error::Thread)?;
    // Unique enough among the asks a ground station makes: when, and by which process.
    let id = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(1, |d| d.as_nanos() as u64 ^ u64::from(std::process::id()));
    let message = StringMessage {
        data: serde_json::to_string(&request(id, changes)).unwrap_or_default(),
    };
    let started = Instant::now();
    let deadline = started + Duration::from_secs_f64(timeout_s);
    while requests.get_subscription_count(&node) == 0 || answers.get_publisher_count(&node) == 0 {
        if Instant::now() >= deadline {
            return Ok(None);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let found_s = started.elapsed().as_secs_f64();
    let asked = Instant::now();
    let mut last_send = asked - Duration::from_secs(1);
    while Instant::now() < deadline {
        if last_send.elapsed() >= Duration::from_millis(100) {
            let _ = requests.publish(message.clone());
            last_send = Instant::now();
        }
        while let Ok(Some((message, _))) = answers.take() {
            let Ok(answer) = serde_json::from_str::<PlanAnswer>(&message.data) else {
                continue;
            };
            if answer.id == id {
                return Ok(Some(Asked {
                    answer,
                    found_s,
                    answered_ms: asked.elapsed().as_secs_f64() * 1e3,
                }));
            }
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    Ok(None)
}

#[cfg(test)]
mod tests {
    use super::*;
    use power_models::planner::LevelRange;

    #[test]
    fn a_change_is_a_known_key_and_a_value() {
        let parsed = |text: &str| {
            let mut request = PlanRequest::default();
            request.add_change(text).map(|()| request)
        };
        assert_eq!(parsed("reserve=0.3").unwrap().reserve_fraction, Some(0.3));
        assert_eq!(parsed("time_left_s=600").unwrap().time_left_s, Some(600.0));
        assert_eq!(
            parsed("hazard=1..3").unwrap().levels["hazard"],
            Some(LevelRange { min: 1, max: 3 })
        );
        assert_eq!(
            parsed("hazard=2").unwrap().levels["hazard"],
            Some(LevelRange { min: 2, max: 2 })
        );
        assert_eq!(parsed("hazard=all").unwrap().levels["hazard"], None);
        assert!(parse_change("reserve").unwrap_err().contains("KEY=VALUE"));
        assert!(parse_change("reserve=lots")
            .unwrap_err()
            .contains("not a number"));
        assert!(parse_change("hazard=high")
            .unwrap_err()
            .contains("hazard=MIN..MAX"));
        assert!(parse_change("=3").unwrap_err().contains("names nothing"));
    }

    #[test]
    fn the_changes_of_one_set_go_in_one_request() {
        let asked = request(
            7,
            &[
                "reserve=0.3".into(),
                "time_left_s=120".into(),
                "hazard=all".into(),
            ],
        );
        let json = serde_json::to_value(&asked).unwrap();
        assert_eq!(
            json,
            serde_json::json!({
                "id": 7, "reserve_fraction": 0.3, "time_left_s": 120.0,
                "levels": {"hazard": null}
            })
        );
    }
}
