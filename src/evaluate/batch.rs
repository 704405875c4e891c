//! What a batch scheduler tells one task of a sweep: which shard it is (`--shard auto`, from the
//! scheduler's own index variables, so one job script serves every task of the array) and how
//! many cores it was given.
//!
//! - Slurm job arrays set `SLURM_ARRAY_TASK_ID`, `SLURM_ARRAY_TASK_MIN`, `SLURM_ARRAY_TASK_MAX`,
//!   `SLURM_ARRAY_TASK_STEP` and `SLURM_ARRAY_TASK_COUNT` (sbatch(1), "OUTPUT ENVIRONMENT
//!   VARIABLES"). `--array=1-4`, `--array=0-3` and `--array=0-6:2` each make four shards.
//! - Kubernetes Indexed Jobs set `JOB_COMPLETION_INDEX` (0 to completions − 1) but not the
//!   completions: the count comes with the flag, `--shard auto/N`.

use super::grid::{parse_shard, Shard};
use std::fmt;

/// What `--shard` says: a shard, or to ask the scheduler (with the count where it is given).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShardSpec {
    Fixed(Shard),
    Auto { count: Option<usize> },
}

/// `--shard I/N`, `--shard auto` or `--shard auto/N`.
pub fn parse_shard_spec(text: &str) -> Result<ShardSpec, String> {
    let Some(rest) = text.trim().strip_prefix("auto") else {
        return parse_shard(text).map(ShardSpec::Fixed);
    };
    if rest.is_empty() {
        return Ok(ShardSpec::Auto { count: None });
    }
    let count = rest
        .strip_prefix('/')
        .and_then(|n| n.trim().parse::<usize>().ok())
        .filter(|&n| n >= 1)
        .ok_or_else(|| {
            format!("expected auto or auto/N (N ≥ 1, the number of shards), found `{text}`")
        })?;
    Ok(ShardSpec::Auto { count: Some(count) })
}

/// Where an automatic shard came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ShardSource {
    Slurm {
        job_id: Option<String>,
        task_id: i64,
    },
    Kubernetes {
        completion_index: usize,
    },
}

impl fmt::Display for ShardSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Slurm { job_id, task_id } => {
                write!(f, "Slurm array task {task_id}")?;
                match job_id {
                    Some(job) => write!(f, " of job {job}"),
                    None => Ok(()),
                }
            }
            Self::Kubernetes { completion_index } => {
                write!(f, "Kubernetes completion index {completion_index}")
            }
        }
    }
}

/// Why no shard could be taken from the environment.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AutoShardError {
    #[error(
        "--shard auto: no scheduler index in the environment (SLURM_ARRAY_TASK_ID for a Slurm \
         job array, JOB_COMPLETION_INDEX for a Kubernetes Indexed Job); outside one, give \
         --shard I/N"
    )]
    NoIndex,
    #[error("--shard auto: {variable}={value:?} is not a whole number")]
    NotANumber {
        variable: &'static str,
        value: String,
    },
    #[error(
        "--shard auto: the Slurm array is not described: {variable} is not set beside \
         SLURM_ARRAY_TASK_ID (submit with sbatch --array)"
    )]
    SlurmIncomplete { variable: &'static str },
    #[error("--shard auto: {why}")]
    Inconsistent { why: String },
    #[error(
        "--shard auto: JOB_COMPLETION_INDEX={index} but the Job's completions are not known here; \
         give them as --shard auto/N (N = spec.completions)"
    )]
    KubernetesCount { index: usize },
}

/// The cores a Slurm task was given (`--cpus-per-task`, SLURM_CPUS_PER_TASK), where the
/// scheduler does not confine it to them itself (no cgroup or affinity plugin); `None` outside
/// Slurm or for a value that is no count.
pub fn allotted_cpus(env: impl Fn(&str) -> Option<String>) -> Option<usize> {
    env("SLURM_CPUS_PER_TASK")?
        .trim()
        .parse::<usize>()
        .ok()
        .filter(|&n| n >= 1)
}

/// The shard `spec` names: itself, or the one the scheduler's variables (`env`) say.
pub fn resolve_shard(
    spec: ShardSpec,
    env: impl Fn(&str) -> Option<String>,
) -> Result<(Shard, Option<ShardSource>), AutoShardError> {
    let given_count = match spec {
        ShardSpec::Fixed(shard) => return Ok((shard, None)),
        ShardSpec::Auto { count } => count,
    };
    if env("SLURM_ARRAY_TASK_ID").is_some() {
        let (shard, source) = slurm_shard(&env)?;
        check_count(shard, given_count, &source)?;
        return Ok((shard, Some(source)));
    }
    if let Some(index) = env("JOB_COMPLETION_INDEX") {
        let completion_index = number("JOB_COMPLETION_INDEX", &index)?;
        let completion_index =
            usize::try_from(completion_index).map_err(|_| AutoShardError::NotANumber {
                variable: "JOB_COMPLETION_INDEX",
                value: index.clone(),
            })?;
        let count = given_count.ok_or(AutoShardError::KubernetesCount {
            index: completion_index,
        })?;
        if completion_index >= count {
            return Err(AutoShardError::Inconsistent {
                why: format!(
                    "JOB_COMPLETION_INDEX={completion_index} is not below the {count} shards of \
                     --shard auto/{count} (indices run from 0 to completions − 1)"
                ),
            });
        }
        let shard = Shard {
            index: completion_index + 1,
            count,
        };
        return Ok((shard, Some(ShardSource::Kubernetes { completion_index })));
    }
    Err(AutoShardError::NoIndex)
}

/// The shard of a Slurm array task: its place among the array's ids, counted from 1.
fn slurm_shard(
    env: &impl Fn(&str) -> Option<String>,
) -> Result<(Shard, ShardSource), AutoShardError> {
    let read = |variable: &'static str| -> Result<Option<i64>, AutoShardError> {
        env(variable)
            .map(|value| number(variable, &value))
            .transpose()
    };
    let required = |variable: &'static str| {
        read(variable)?.ok_or(AutoShardError::SlurmIncomplete { variable })
    };
    let task_id = required("SLURM_ARRAY_TASK_ID")?;
    let min = required("SLURM_ARRAY_TASK_MIN")?;
    let max = required("SLURM_ARRAY_TASK_MAX")?;
    let step = read("SLURM_ARRAY_TASK_STEP")?.unwrap_or(1);
    let inconsistent = |why: String| AutoShardError::Inconsistent { why };
    if step < 1 || max < min {
        return Err(inconsistent(format!(
            "the Slurm array {min}-{max}:{step} is empty or runs backwards"
        )));
    }
    if task_id < min || task_id > max || (task_id - min) % step != 0 {
        return Err(inconsistent(format!(
            "SLURM_ARRAY_TASK_ID={task_id} is not one of the array {min}-{max}:{step}"
        )));
    }
    let count = ((max - min) / step + 1) as usize;
    if let Some(said) = read("SLURM_ARRAY_TASK_COUNT")? {
        // An array with gaps (--array=1,3,7) numbers its tasks by id, not by place: the
        // shards would not cover the sweep.
        if said != count as i64 {
            return Err(inconsistent(format!(
                "SLURM_ARRAY_TASK_COUNT={said} but the array {min}-{max}:{step} has {count} \
                 tasks; submit an evenly stepped array (--array=1-N)"
            )));
        }
    }
    let shard = Shard {
        index: ((task_id - min) / step + 1) as usize,
        count,
    };
    let source = ShardSource::Slurm {
        job_id: env("SLURM_ARRAY_JOB_ID"),
        task_id,
    };
    Ok((shard, source))
}

/// A count given with `--shard auto/N` must be the scheduler's.
fn check_count(
    shard: Shard,
    given: Option<usize>,
    source: &ShardSource,
) -> Result<(), AutoShardError> {
    match given {
        Some(count) if count != shard.count => Err(AutoShardError::Inconsistent {
            why: format!(
                "--shard auto/{count} but {source} is in an array of {} tasks",
                shard.count
            ),
        }),
        _ => Ok(()),
    }
}

fn number(variable: &'static str, value: &str) -> Result<i64, AutoShardError> {
    value
        .trim()
        .parse::<i64>()
        .map_err(|_| AutoShardError::NotANumber {
            variable,
            value: value.to_string(),
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    fn env<'a>(pairs: &'a [(&'a str, &'a str)]) -> impl Fn(&str) -> Option<String> + 'a {
        let map: HashMap<&str, &str> = pairs.iter().copied().collect();
        move |name| map.get(name).map(|v| v.to_string())
    }

    fn auto(count: Option<usize>) -> ShardSpec {
        ShardSpec::Auto { count }
    }

    #[test]
    fn a_slurm_task_runs_on_the_cores_it_was_given() {
        assert_eq!(allotted_cpus(env(&[("SLURM_CPUS_PER_TASK", "2")])), Some(2));
        assert_eq!(allotted_cpus(env(&[])), None);
        assert_eq!(allotted_cpus(env(&[("SLURM_CPUS_PER_TASK", "0")])), None);
        assert_eq!(allotted_cpus(env(&[("SLURM_CPUS_PER_TASK", "two")])), None);
    }

    #[test]
    fn specs_parse() {
        assert_eq!(parse_shard_spec("auto"), Ok(auto(None)));
        assert_eq!(parse_shard_spec("auto/8"), Ok(auto(Some(8))));
        assert_eq!(
            parse_shard_spec("2/4"),
            Ok(ShardSpec::Fixed(Shard { index: 2, count: 4 }))
        );
        for bad in ["auto/0", "auto/x", "autox", "auto/"] {
            assert!(parse_shard_spec(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_slurm_array_task_is_its_place_in_the_array() {
        // --array=1-4, --array=0-3 and --array=0-6:2: the third task is shard 3 of 4 in each.
        for (task_id, min, max, step) in [
            ("3", "1", "4", None),
            ("2", "0", "3", None),
            ("4", "0", "6", Some("2")),
        ] {
            let mut vars = vec![
                ("SLURM_ARRAY_TASK_ID", task_id),
                ("SLURM_ARRAY_TASK_MIN", min),
                ("SLURM_ARRAY_TASK_MAX", max),
                ("SLURM_ARRAY_TASK_COUNT", "4"),
                ("SLURM_ARRAY_JOB_ID", "77"),
            ];
            if let Some(step) = step {
                vars.push(("SLURM_ARRAY_TASK_STEP", step));
            }
            let (shard, source) = resolve_shard(auto(None), env(&vars)).unwrap();
            assert_eq!(shard, Shard { index: 3, count: 4 }, "{vars:?}");
            let source = source.unwrap().to_string();
            assert_eq!(source, format!("Slurm array task {task_id} of job 77"));
            // The count given must agree.
            assert!(resolve_shard(auto(Some(4)), env(&vars)).is_ok());
            assert!(matches!(
                resolve_shard(auto(Some(5)), env(&vars)),
                Err(AutoShardError::Inconsistent { .. })
            ));
        }
    }

    #[test]
    fn a_kubernetes_completion_index_needs_the_count() {
        let vars = [("JOB_COMPLETION_INDEX", "0")];
        let (shard, source) = resolve_shard(auto(Some(3)), env(&vars)).unwrap();
        assert_eq!(shard, Shard { index: 1, count: 3 });
        assert_eq!(
            source,
            Some(ShardSource::Kubernetes {
                completion_index: 0
            })
        );
        assert_eq!(
            resolve_shard(auto(None), env(&vars)),
            Err(AutoShardError::KubernetesCount { index: 0 })
        );
        let past = [("JOB_COMPLETION_INDEX", "3")];
        assert!(matches!(
            resolve_shard(auto(Some(3)), env(&past)),
            Err(AutoShardError::Inconsistent { .. })
        ));
    }

    #[test]
    fn missing_or_inconsistent_indices_are_named() {
        assert_eq!(
            resolve_shard(auto(None), env(&[])),
            Err(AutoShardError::NoIndex)
        );
        let fixed = Shard { index: 2, count: 2 };
        assert_eq!(
            resolve_shard(
                ShardSpec::Fixed(fixed),
                env(&[("SLURM_ARRAY_TASK_ID", "1")])
            ),
            Ok((fixed, None))
        );
        let cases: [(&[(&str, &str)], &str); 5] = [
            (
                &[("SLURM_ARRAY_TASK_ID", "1")],
                "SLURM_ARRAY_TASK_MIN is not set",
            ),
            (
                &[
                    ("SLURM_ARRAY_TASK_ID", "x"),
                    ("SLURM_ARRAY_TASK_MIN", "1"),
                    ("SLURM_ARRAY_TASK_MAX", "4"),
                ],
                "\"x\" is not a whole number",
            ),
            (
                &[
                    ("SLURM_ARRAY_TASK_ID", "9"),
                    ("SLURM_ARRAY_TASK_MIN", "1"),
                    ("SLURM_ARRAY_TASK_MAX", "4"),
                ],
                "not one of the array 1-4:1",
            ),
            (
                &[
                    ("SLURM_ARRAY_TASK_ID", "3"),
                    ("SLURM_ARRAY_TASK_MIN", "1"),
                    ("SLURM_ARRAY_TASK_MAX", "7"),
                    ("SLURM_ARRAY_TASK_COUNT", "3"),
                ],
                "SLURM_ARRAY_TASK_COUNT=3 but the array 1-7:1 has 7 tasks",
            ),
            (&[("JOB_COMPLETION_INDEX", "-1")], "is not a whole number"),
        ];
        for (vars, wanted) in cases {
            let error = resolve_shard(auto(Some(4)), env(vars))
                .unwrap_err()
                .to_string();
            assert!(error.contains(wanted), "{vars:?}: {error}");
        }
    }
}
