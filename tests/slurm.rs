//! A landing-evaluation sweep on a live single-node Slurm cluster, submitted with the files
//! under `deploy/slurm/`: the merged table must equal the unsharded one to the digit; a killed
//! array task leaves a hole the merge names, and the requeued task fills it.
//!
//! The cluster is Debian's Slurm (`slurmctld`, `slurmd`, `slurm-client`, `munge`; `.ci/run`
//! installs them): the test writes a munge key and a `slurm.conf` for this host into a
//! temporary folder and runs munged, slurmctld and slurmd there, stopping them when it ends.
//! It skips, saying why, where Slurm is not installed or the test is not root (slurmd starts
//! jobs as their user).

mod common;
use common::repo_root;
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The sweep: two cells of two seeds, four missions, a few seconds each.
const SWEEP: &str =
    "--worlds ideal --rates 10 --winds 0 --paths straight,turn180 --runs 2 --tracking-s 3";
const SHARDS: usize = 4;
/// Longest the test waits for a job.
const JOB_TIMEOUT: Duration = Duration::from_secs(240);

/// Why the test cannot run here, if it cannot.
fn unavailable() -> Option<String> {
    for tool in [
        "munged",
        "slurmctld",
        "slurmd",
        "sbatch",
        "squeue",
        "scontrol",
        "sinfo",
    ] {
        let found = Command::new("sh")
            .args(["-c", &format!("command -v {tool}")])
            .output()
            .is_ok_and(|o| o.status.success());
        if !found {
            return Some(format!(
                "`{tool}` is not installed (apt-get install slurmctld slurmd slurm-client munge; .ci/run does)"
            ));
        }
    }
    let uid = Command::new("id").arg("-u").output().ok()?;
    if String::from_utf8_lossy(&uid.stdout).trim() != "0" {
        return Some("slurmd must run as root to start jobs".into());
    }
    None
}

/// A port nothing listens on now.
fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// munged, slurmctld and slurmd in a folder of their own; stopped when dropped.
struct Cluster {
    dir: tempfile::TempDir,
    conf: PathBuf,
    daemons: Vec<Child>,
    munge_pid: PathBuf,
}

impl Cluster {
    fn start() -> Cluster {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().to_path_buf();
        for sub in ["state", "spool", "munge"] {
            std::fs::create_dir_all(root.join(sub)).unwrap();
        }
        // munge: a key of our own and a socket in the folder.
        let key = root.join("munge/munge.key");
        let bytes: Vec<u8> = (0..1024u32)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 7) as u8)
            .collect();
        std::fs::write(&key, bytes).unwrap();
        set_mode(&key, 0o400);
        set_mode(&root.join("munge"), 0o700);
        let socket = root.join("munge/munge.socket");
        let munge_pid = root.join("munge/munged.pid");
        let status = Command::new("munged")
            .arg("--force")
            .arg(format!("--key-file={}", key.display()))
            .arg(format!("--socket={}", socket.display()))
            .arg(format!("--pid-file={}", munge_pid.display()))
            .arg(format!(
                "--log-file={}",
                root.join("munge/munged.log").display()
            ))
            .arg(format!(
                "--seed-file={}",
                root.join("munge/munged.seed").display()
            ))
            .status()
            .unwrap();
        assert!(
            status.success(),
            "munged did not start: {}",
            log(&root.join("munge/munged.log"))
        );

        let host = String::from_utf8(Command::new("hostname").arg("-s").output().unwrap().stdout)
            .unwrap()
            .trim()
            .to_string();
        let conf = root.join("slurm.conf");
        std::fs::write(&conf, slurm_conf(&root, &host, &socket)).unwrap();
        let mut cluster = Cluster {
            dir,
            conf,
            daemons: Vec::new(),
            munge_pid,
        };
        for daemon in ["slurmctld", "slurmd"] {
            let child = Command::new(daemon)
                .args(["-D", "-f"])
                .arg(&cluster.conf)
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .unwrap();
            cluster.daemons.push(child);
        }
        cluster.wait_for_node(&host);
        cluster
    }

    fn root(&self) -> &Path {
        self.dir.path()
    }

    /// A Slurm command against this cluster.
    fn command(&self, program: &str) -> Command {
        let mut command = Command::new(program);
        command.env("SLURM_CONF", &self.conf);
        command
    }

    fn run(&self, program: &str, args: &[&str]) -> String {
        let output = self.command(program).args(args).output().unwrap();
        assert!(
            output.status.success(),
            "{program} {args:?}: {}",
            text(&output)
        );
        String::from_utf8(output.stdout).unwrap()
    }

    fn wait_for_node(&self, host: &str) {
        let started = Instant::now();
        loop {
            let state = self
                .command("sinfo")
                .args(["-h", "-n", host, "-o", "%T"])
                .output()
                .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
                .unwrap_or_default();
            if state == "idle" {
                return;
            }
            assert!(
                started.elapsed() < Duration::from_secs(60),
                "the node is `{state}`, not idle, after 60 s\nslurmctld: {}\nslurmd: {}",
                log(&self.root().join("slurmctld.log")),
                log(&self.root().join("slurmd.log"))
            );
            std::thread::sleep(Duration::from_millis(250));
        }
    }

    /// Waits until none of `jobs` is pending or running any more.
    fn wait_until_gone(&self, jobs: &[&str]) {
        let started = Instant::now();
        loop {
            let queued = self.run("squeue", &["-h", "-o", "%i %T", "-j", &jobs.join(",")]);
            if queued.trim().is_empty() {
                return;
            }
            assert!(
                started.elapsed() < JOB_TIMEOUT,
                "still queued after {JOB_TIMEOUT:?}:\n{queued}\nslurmctld: {}",
                log(&self.root().join("slurmctld.log"))
            );
            std::thread::sleep(Duration::from_millis(250));
        }
    }

    /// Waits until `job` is in one of `states` (as `squeue` prints them).
    fn wait_for_state(&self, job: &str, states: &[&str]) -> String {
        let started = Instant::now();
        loop {
            let state = self.run("squeue", &["-h", "-o", "%T", "-j", job]);
            let state = state.trim().to_string();
            if states.contains(&state.as_str()) {
                return state;
            }
            assert!(
                started.elapsed() < JOB_TIMEOUT,
                "job {job} is `{state}`, not one of {states:?}"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Submits `sweep` in `SHARDS` shards with deploy/slurm/submit.sh: the array job's id and
    /// the merge's.
    fn submit(&self, sweep_dir: &Path, sweep: &str) -> (String, String) {
        let submit = repo_root().join("deploy/slurm/submit.sh");
        let output = self
            .command("bash")
            .arg(&submit)
            .arg(SHARDS.to_string())
            .arg(format!("--chdir={}", self.root().display()))
            // One core a shard: two shards fly at once on this two-core node.
            .arg("--cpus-per-task=1")
            .env("QOSRT", env!("CARGO_BIN_EXE_qosrt"))
            .env("QOSRT_CONFIG", repo_root().join("qos.toml"))
            .env("QOSRT_SWEEP", sweep)
            .env("QOSRT_SWEEP_DIR", sweep_dir)
            .output()
            .unwrap();
        assert!(output.status.success(), "submit.sh: {}", text(&output));
        let ids = String::from_utf8(output.stdout).unwrap();
        let mut ids = ids.split_whitespace().map(str::to_string);
        (ids.next().unwrap(), ids.next().unwrap())
    }

    /// Each array task's wait from submission to start, seconds (Slurm's own times, to the
    /// second).
    fn queue_waits_s(&self, array: &str) -> Vec<i64> {
        let shown = self.run("scontrol", &["-o", "show", "job", array]);
        shown
            .lines()
            .filter_map(|line| {
                let time = |key: &str| {
                    line.split_whitespace()
                        .find_map(|w| w.strip_prefix(key))
                        .and_then(seconds_of)
                };
                Some(time("StartTime=")? - time("SubmitTime=")?)
            })
            .collect()
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        for child in &mut self.daemons {
            let _ = child.kill();
            let _ = child.wait();
        }
        if let Ok(pid) = std::fs::read_to_string(&self.munge_pid) {
            let _ = Command::new("kill").arg(pid.trim()).status();
        }
    }
}

/// `2026-12-06T10:43:07` as seconds of the day, enough to subtract two times of one run.
fn seconds_of(stamp: &str) -> Option<i64> {
    let (date, time) = stamp.split_once('T')?;
    let day: i64 = date.rsplit('-').next()?.parse().ok()?;
    let mut parts = time.split(':').map(|p| p.parse::<i64>().ok());
    let (h, m, s) = (parts.next()??, parts.next()??, parts.next()??);
    Some(((day * 24 + h) * 60 + m) * 60 + s)
}

fn slurm_conf(root: &Path, host: &str, munge_socket: &Path) -> String {
    let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
    format!(
        "ClusterName=qosrt-test
SlurmctldHost={host}(127.0.0.1)
SlurmctldPort={ctld}
SlurmdPort={slurmd}
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket={socket}
CredType=cred/munge
StateSaveLocation={root}/state
SlurmdSpoolDir={root}/spool
SlurmctldPidFile={root}/slurmctld.pid
SlurmdPidFile={root}/slurmd.pid
SlurmctldLogFile={root}/slurmctld.log
SlurmdLogFile={root}/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
MpiDefault=none
ReturnToService=2
MinJobAge=600
NodeName={host} NodeAddr=127.0.0.1 CPUs={cpus} State=UNKNOWN
PartitionName=sweep Nodes={host} Default=YES MaxTime=INFINITE State=UP
",
        ctld = free_port(),
        slurmd = free_port(),
        socket = munge_socket.display(),
        root = root.display(),
    )
}

fn set_mode(path: &Path, mode: u32) {
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode)).unwrap();
}

fn log(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(20)..].join("\n")
}

fn text(output: &Output) -> String {
    format!(
        "{}\n{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    )
}

/// `qosrt sim` with `args`, as a user runs it.
fn qosrt_sim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_qosrt"))
        .arg("sim")
        .arg(repo_root().join("qos.toml"))
        .args(args)
        .output()
        .unwrap()
}

/// `qosrt sim --merge` of the sweep folder's shard files, with `extra` flags.
fn merge(sweep_dir: &Path, extra: &[&str]) -> Output {
    let mut files: Vec<PathBuf> = std::fs::read_dir(sweep_dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    files.sort();
    Command::new(env!("CARGO_BIN_EXE_qosrt"))
        .args(["sim", "--merge"])
        .args(&files)
        .args(extra)
        .output()
        .unwrap()
}

/// The unsharded sweep, as one machine flies it: its table and CSV (every figure in full
/// precision), and its wall time.
fn unsharded(sweep: &str) -> (Tables, f64) {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("whole.csv");
    let started = Instant::now();
    let mut args = vec!["--evaluate", "--csv", csv.to_str().unwrap()];
    args.extend(sweep.split_whitespace());
    let whole = qosrt_sim(&args);
    let whole_s = started.elapsed().as_secs_f64();
    assert!(whole.status.success(), "{}", text(&whole));
    let tables = Tables {
        markdown: String::from_utf8(whole.stdout).unwrap(),
        csv: std::fs::read_to_string(csv).unwrap(),
    };
    (tables, whole_s)
}

/// A sweep's table as printed and as CSV.
#[derive(Debug, PartialEq)]
struct Tables {
    markdown: String,
    csv: String,
}

/// `sweep` through submit.sh, waited for: the merged table must be `whole_table`; prints each
/// shard's wait from submission to start and the wall times, sharded and not.
fn sweep_matches(cluster: &Cluster, name: &str, sweep: &str, whole: &Tables, whole_s: f64) {
    let sweep_dir = cluster.root().join(name);
    let started = Instant::now();
    let (array, merge_job) = cluster.submit(&sweep_dir, sweep);
    cluster.wait_until_gone(&[&array, &merge_job]);
    let sharded_s = started.elapsed().as_secs_f64();
    let read = |file: &str| {
        std::fs::read_to_string(sweep_dir.join(file)).unwrap_or_else(|_| {
            panic!(
                "the merge job wrote no {file}:\n{}",
                log(&cluster.root().join(format!("qosrt-merge-{merge_job}.out")))
            )
        })
    };
    let merged = Tables {
        markdown: read("table.md"),
        csv: read("table.csv"),
    };
    assert_eq!(&merged, whole);
    let waits_s = cluster.queue_waits_s(&array);
    assert_eq!(waits_s.len(), SHARDS, "{waits_s:?}");
    eprintln!(
        "Slurm, `{sweep}`: {SHARDS} shards, submit to start {waits_s:?} s; {sharded_s:.1} s from \
         submission to the merged table, {whole_s:.1} s unsharded ({:.2}×)",
        sharded_s / whole_s
    );
}

/// The overhead on a sweep of 24 realistic missions (a minute's flying on two cores), for the
/// figures in docs/cluster.md: `cargo test --release --test slurm -- --ignored --nocapture`.
#[test]
#[ignore = "a minute of flying twice over; the suite runs the small sweep"]
fn a_larger_sweep_on_slurm_costs_little_more_than_unsharded() {
    if let Some(why) = unavailable() {
        eprintln!("skipping the live Slurm sweep: {why}");
        return;
    }
    const LARGER: &str =
        "--worlds realistic --rates 10 --winds 0,12 --paths straight,turn180 --runs 6";
    let (whole, whole_s) = unsharded(LARGER);
    let cluster = Cluster::start();
    sweep_matches(&cluster, "larger", LARGER, &whole, whole_s);
}

#[test]
fn a_sweep_on_slurm_merges_to_the_unsharded_table_and_a_killed_task_is_a_named_hole() {
    if let Some(why) = unavailable() {
        eprintln!("skipping the live Slurm sweep: {why}");
        return;
    }
    let (whole, whole_s) = unsharded(SWEEP);
    assert!(whole.markdown.contains("| builtin | ideal |"), "{whole:?}");
    let cluster = Cluster::start();

    // 1. The array and the merge after it: the merged table is the unsharded one, its CSV to
    // the last digit.
    sweep_matches(&cluster, "sweep", SWEEP, &whole, whole_s);

    // 2. A task killed: the merge names the hole; the requeued task fills it.
    let sweep_dir = cluster.root().join("killed");
    let (array, merge_job) = cluster.submit(&sweep_dir, SWEEP);
    let killed = format!("{array}_2");
    // Killed while it flies, as a node lost or a pod evicted would be.
    cluster.wait_for_state(&killed, &["RUNNING"]);
    cluster.run("scancel", &[&killed]);
    let others: Vec<String> = [1, 3, 4].map(|t| format!("{array}_{t}")).to_vec();
    cluster.wait_until_gone(&others.iter().map(String::as_str).collect::<Vec<_>>());
    // The merge waits for a success that will not come.
    let state = cluster.wait_for_state(&merge_job, &["PENDING"]);
    assert_eq!(state, "PENDING");
    let refused = merge(&sweep_dir, &[]);
    assert_eq!(refused.status.code(), Some(2), "{}", text(&refused));
    let why = String::from_utf8_lossy(&refused.stderr);
    assert!(
        why.contains("shard 2 of 4 is missing") && why.contains("--shard 2/4"),
        "{why}"
    );
    let partial = merge(&sweep_dir, &["--allow-partial"]);
    assert_eq!(partial.status.code(), Some(3), "{}", text(&partial));
    let partial_table = String::from_utf8_lossy(&partial.stdout);
    assert!(
        partial_table.contains("(partial: 1 of 2 runs)"),
        "{partial_table}"
    );
    assert!(String::from_utf8_lossy(&partial.stderr).contains("shard 2 of 4 is missing"));

    assert!(!sweep_dir.join("shard-2.json").exists());
    // Requeued, and let start at once (Slurm holds a requeued job for two minutes).
    cluster.run("scontrol", &["requeue", &killed]);
    cluster.run(
        "scontrol",
        &["update", &format!("JobId={killed}"), "StartTime=now"],
    );
    cluster.wait_until_gone(&[&killed]);
    let filled = merge(&sweep_dir, &[]);
    assert!(filled.status.success(), "{}", text(&filled));
    assert_eq!(String::from_utf8(filled.stdout).unwrap(), whole.markdown);
    cluster.run("scancel", &[&merge_job]);
}
