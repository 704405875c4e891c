//! Flying many missions on all cores.

use crate::sim::args::SimArgs;
use indicatif::{ProgressBar, ProgressStyle};
use runtime::energy::MissionModel;
use runtime::registry::PluginRegistry;
use sitl::mission::{simulate, SimOptions};
use sitl::outcome::SimOutcome;

/// Flies `args.runs` seeds (default 1, from `args.seed`) of every cell, with the options `options_of(cell,
/// seed)`; the outcomes grouped by cell. A mission that cannot be flown is reported, and ends
/// the evaluation.
pub fn fly_cells<C>(
    model: &MissionModel,
    registry: &PluginRegistry,
    cells: &[C],
    args: &SimArgs,
    options_of: impl Fn(&C, u64) -> SimOptions,
) -> Result<Vec<Vec<SimOutcome>>, ()> {
    let mut jobs = Vec::with_capacity(cells.len() * args.runs());
    for (index, cell) in cells.iter().enumerate() {
        for run in 0..args.runs() as u64 {
            jobs.push((index, options_of(cell, args.seed + run)));
        }
    }
    fly_all(model, registry, jobs, cells.len()).map_err(|error| eprintln!("error: {error}"))
}

/// Flies every job on all cores with a progress bar (on stderr, hidden when that is no
/// terminal); the outcomes grouped by the job's cell, each cell's in the order of their seeds
/// whatever order the workers finished in, so that statistics summed over them come out the same
/// on every run.
pub fn fly_all(
    model: &MissionModel,
    registry: &PluginRegistry,
    jobs: Vec<(usize, SimOptions)>,
    cells: usize,
) -> Result<Vec<Vec<SimOutcome>>, String> {
    let bar = ProgressBar::new(jobs.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} missions, {elapsed} elapsed, ETA {eta}")
            .expect("a valid template"),
    );
    // A real autopilot per worker, each its own instance (its own ports); one the user started
    // serves one mission at a time.
    let real = jobs.first().and_then(|(_, o)| o.autopilot.clone());
    let workers = match &real {
        Some(autopilot) if autopilot.command.is_none() => 1,
        _ => {
            let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
            // A batch task flies on the cores it was given, not on the whole node.
            super::batch::allotted_cpus(|name| std::env::var(name).ok())
                .map_or(cores, |given| given.min(cores))
        }
    };
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results = std::sync::Mutex::new(vec![Vec::new(); cells]);
    let failure = std::sync::Mutex::new(None);
    std::thread::scope(|scope| {
        for worker in 0..workers {
            let (next, results, failure, bar, jobs) = (&next, &results, &failure, &bar, &jobs);
            scope.spawn(move || loop {
                let index = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some((cell, options)) = jobs.get(index) else {
                    break;
                };
                let mut options = options.clone();
                if let Some(autopilot) = options.autopilot.as_mut() {
                    autopilot.instance += worker as u8;
                }
                match simulate(model, registry, &options) {
                    Ok(outcome) => results.lock().expect("no worker panics")[*cell].push(outcome),
                    Err(error) => {
                        *failure.lock().expect("no worker panics") =
                            Some(format!("seed {}: {error}", options.world.seed));
                        break;
                    }
                }
                bar.inc(1);
            });
        }
    });
    bar.finish_and_clear();
    if let Some(error) = failure.into_inner().expect("no worker panics") {
        return Err(error);
    }
    let mut results = results.into_inner().expect("no worker panics");
    for outcomes in &mut results {
        outcomes.sort_by_key(|o| o.seed);
    }
    Ok(results)
}
