//! `qosrt sim`'s arguments.

use sim::realism::Realism;
use sim::tractor::PathKind;
use sim::wind::WindKind;
use sim::world::WorldOptions;
use sitl::mission::{AutopilotKind, Faults, RealAutopilot, SimOptions};
use std::path::PathBuf;

/// `qosrt sim`'s arguments.
#[derive(clap::Args)]
pub struct SimArgs {
    /// The mission config.
    #[arg(default_value = "qos.toml")]
    pub file: PathBuf,
    /// The tractor's path: straight, s-shape, rectangle, circle, figure8, turn90, turn180.
    #[arg(long, default_value = "straight")]
    pub path: PathKind,
    /// Mean wind speed (the seed's gust model).
    #[arg(
        long = "wind-m-s",
        alias = "wind-mps",
        default_value_t = 0.0,
        value_name = "M_S"
    )]
    pub wind_m_s: f64,
    /// Dryden turbulence around the mean wind instead of the seed's gusts.
    #[arg(long)]
    pub dryden: bool,
    /// The tractor's speed.
    #[arg(
        long = "platform-speed-m-s",
        alias = "platform-speed-mps",
        default_value_t = 1.5,
        value_name = "M_S"
    )]
    pub platform_speed_m_s: f64,
    /// Random seed (wind, camera noise, hazards); the same seed flies the same mission.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Fly this many seeds (seed, seed + 1, ...) and print a summary; with an evaluation, seeds
    /// per cell (default: 20 for --evaluate, 1 for the others).
    #[arg(long, value_name = "N")]
    pub runs: Option<usize>,
    /// Fly the ideal world (the autopilot hands out the truth, frames arrive at once, a still
    /// pad) instead of the realistic one.
    #[arg(long, conflicts_with = "serve")]
    pub ideal: bool,
    /// Override the tracking phase's duration (s), e.g. to evaluate landings.
    #[arg(long, value_name = "S")]
    pub tracking_s: Option<f64>,
    /// Hold a task at one of its levels, by knob value: --fix detection=10 (repeatable).
    #[arg(long = "fix", value_name = "TASK=VALUE", value_parser = crate::args::parse_fixed_level)]
    pub fixed_levels: Vec<(String, f64)>,
    /// Ask for a plan change at a mission time, as a ground station would with `qosrt fleet
    /// set`: --plan-change 300:reserve=0.35,hazard=0..1 (repeatable; KEY=VALUE as `qosrt fleet
    /// set` takes them).
    #[arg(
        long = "plan-change",
        value_name = "AT_S:KEY=VALUE,…",
        conflicts_with = "serve"
    )]
    pub plan_changes: Vec<sitl::mission::ScheduledPlanChange>,
    /// Print the outcome as JSON.
    #[arg(long)]
    pub json: bool,
    /// Draw the vehicle's and the tractor's tracks and the battery over time as SVG.
    #[arg(long, value_name = "PATH")]
    pub svg: Option<PathBuf>,
    /// Evaluate landings: world {realistic, ideal} × landing-marker rate × wind {0, 8 and 12 m/s
    /// gusts, 12 m/s Dryden} × path {straight, figure8, turn180} with the tractor at 1.5 m/s, and
    /// per world and rate the tractor at 3 m/s on turn180 in 8 m/s gusts; --runs seeds per cell
    /// (default 20; tracking 15 s unless --tracking-s says otherwise), as a table.
    #[arg(long, conflicts_with_all = ["path", "wind_m_s", "dryden", "platform_speed_m_s", "svg"])]
    pub evaluate: bool,
    /// The evaluation's worlds: realistic, ideal (default both; --ideal: ideal only).
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        requires = "evaluate",
        conflicts_with = "ideal"
    )]
    pub worlds: Vec<crate::evaluate::grid::World>,
    /// The evaluation's landing-marker rates, among the config's levels (default all).
    #[arg(
        long,
        value_name = "FPS,…",
        value_delimiter = ',',
        requires = "evaluate"
    )]
    pub rates: Vec<f64>,
    /// The evaluation's winds: 0, 8, 12 (m/s, gusts), dryden12 (default all).
    #[arg(long, value_name = "WIND,…", value_delimiter = ',', value_parser = crate::evaluate::grid::parse_wind, requires = "evaluate")]
    pub winds: Vec<crate::evaluate::grid::GridWind>,
    /// The evaluation's paths: straight, figure8, turn180 (default all).
    #[arg(long, value_name = "PATH,…", value_delimiter = ',', value_parser = crate::evaluate::grid::parse_grid_path, requires = "evaluate")]
    pub paths: Vec<PathKind>,
    /// Fly only shard I of N of the evaluation (the missions k with k mod N = I − 1) and write
    /// its runs as a shard file (to --out, else stdout) for --merge. `auto`: the shard a Slurm
    /// array task is (SLURM_ARRAY_TASK_ID and the array's bounds); `auto/N`: of N shards, as a
    /// Kubernetes Indexed Job's JOB_COMPLETION_INDEX says (or as a check on Slurm's count).
    #[arg(long, value_name = "I/N|auto[/N]", value_parser = crate::evaluate::batch::parse_shard_spec, requires = "evaluate")]
    pub shard: Option<crate::evaluate::batch::ShardSpec>,
    /// Write the evaluation's runs as a shard file (the whole evaluation as shard 1/1).
    #[arg(long, value_name = "PATH", requires = "evaluate")]
    pub out: Option<PathBuf>,
    /// Also write the evaluation's table as CSV, one row per cell.
    #[arg(long, value_name = "PATH", conflicts_with = "shard")]
    pub csv: Option<PathBuf>,
    /// Fly nothing: join the shard files of a sweep (`--evaluate --shard I/N --out FILE`) into
    /// the table the unsharded evaluation prints.
    #[arg(long, value_name = "SHARD.json", num_args = 1.., conflicts_with_all = ["evaluate", "evaluate_hazards", "evaluate_paths", "serve", "ideal", "runs", "seed", "svg", "tracking_s", "fixed_levels", "path", "wind_m_s", "dryden", "platform_speed_m_s"])]
    pub merge: Vec<PathBuf>,
    /// With --merge: print the table even when shards are missing, their cells marked with the
    /// runs they lack (the missing shards are still named, and the exit status says so).
    #[arg(long, requires = "merge")]
    pub allow_partial: bool,
    /// Evaluate hazard detection as the seed scored it (a hazard seen = a detection of its class
    /// within 2 m): every hazard-CNN rate × wind {0, 8, 12} m/s on the straight path, --runs
    /// seeds per cell (tracking 200 s, 32 hazards beside the track, unless --tracking-s says
    /// otherwise), as a table.
    #[arg(long, conflicts_with = "evaluate")]
    pub evaluate_hazards: bool,
    /// Seed 000's simulated trials (§3.1): path {straight, s-shape, rectangle, circle, figure8}
    /// × UGV speed {0.2, 0.5, 0.8} m/s, following at the landing task's IH, --runs seeds per
    /// cell (tracking 30 s, the rectangle's until past its first corner, unless --tracking-s
    /// says otherwise; the marker detector at its top rate), with the localisation error while
    /// tracking, the touchdown error and the success rate, as a table.
    #[arg(long, conflicts_with_all = ["evaluate", "evaluate_hazards"])]
    pub evaluate_paths: bool,
    /// Serve the world as its own process on the wall clock, standing in for PX4 SITL + Gazebo:
    /// MAVLink to UDP --mavlink-port, the camera as RTP/H.264 to UDP --video-port; fly it with
    /// `qosrt run --mavlink udpin:0.0.0.0:14540 --camera rtp-h264:5600 --control`.
    #[arg(long, conflicts_with_all = ["evaluate", "evaluate_hazards", "evaluate_paths", "runs", "svg", "fixed_levels", "tracking_s"])]
    pub serve: bool,
    /// Who flies the served vehicle: sim (the world's own), px4-sih[:INSTANCE] (PX4 SITL's
    /// SIH, whose true pose the world reads on UDP 19410+INSTANCE), px4-hil[:INSTANCE] (a PX4
    /// you started with `-m none_iris`, the world its HIL simulator on TCP 4560+INSTANCE) or
    /// ardupilot-json[:INSTANCE] (an ArduCopter you started with `-M JSON:127.0.0.1`, the world
    /// its physics on UDP 9002+10·INSTANCE). A real autopilot's MAVLink is its own: `qosrt run
    /// --mavlink udpin:0.0.0.0:14540+INSTANCE` (PX4) or `tcpout:127.0.0.1:5760+10·INSTANCE`
    /// (ArduPilot).
    #[arg(long, default_value = "sim", requires = "serve")]
    pub vehicle: sitl::serve::ServeVehicle,
    /// The UDP port on 127.0.0.1 the simulated autopilot sends MAVLink to.
    #[arg(long, default_value_t = 14540, requires = "serve")]
    pub mavlink_port: u16,
    /// The UDP port on 127.0.0.1 the camera's RTP/H.264 stream goes to.
    #[arg(long, default_value_t = 5600, requires = "serve")]
    pub video_port: u16,
    /// Serve MAVLink only, no camera stream.
    #[arg(long, requires = "serve")]
    pub no_video: bool,
    /// Where the tractor waits, metres north and east of the take-off point (with --serve, give
    /// `qosrt run` the same).
    #[arg(long, value_name = "N,E", value_parser = crate::args::parse_north_east, default_value = "15,0")]
    pub meeting_point_ne_m: [f64; 2],
    /// The served world stops after this long.
    #[arg(long, value_name = "S", default_value_t = 600.0, requires = "serve")]
    pub max_time_s: f64,
    /// Who flies the vehicle: builtin (the world's own PX4-like autopilot, fast and
    /// deterministic), px4 (a real PX4 with a `none_iris`-style airframe, the world its HIL
    /// simulator on TCP 4560+i) or ardupilot (a real ArduPilot Copter, the world its JSON
    /// physics backend on UDP 9002+10i). The runtime talks to it over MAVLink as on a drone.
    #[arg(long, default_value = "builtin", conflicts_with = "serve")]
    pub autopilot: sitl::mission::AutopilotKind,
    /// The command that starts one autopilot instance, `{i}` replaced by its number, e.g.
    /// `'../shared/px4-sitl/start -i {i} -m none_iris'` or `make px4_sitl none_iris`; without
    /// it qosrt waits for an autopilot you started (instance --autopilot-instance).
    #[arg(long, value_name = "CMD")]
    pub autopilot_cmd: Option<String>,
    /// The real autopilot's instance number (with --autopilot-cmd, the first of one per worker).
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub autopilot_instance: u8,
    #[command(flatten)]
    pub recording: crate::args::RecordArgs,
}

impl SimArgs {
    /// One mission as the arguments describe it, flown with `seed`.
    pub(crate) fn options(&self, seed: u64) -> SimOptions {
        SimOptions {
            world: self.world(seed),
            tracking_s: self.tracking_s,
            fixed_levels: self.fixed_levels.clone(),
            faults: Faults::default(),
            record_track: self.svg.is_some(),
            autopilot: (self.autopilot != AutopilotKind::Builtin).then(|| RealAutopilot {
                kind: self.autopilot,
                instance: self.autopilot_instance,
                command: self.autopilot_cmd.clone(),
                connect_timeout: std::time::Duration::from_secs(60),
            }),
            ros2_vehicle: self.recording.ros2.clone(),
            plan_changes: self.plan_changes.clone(),
            // ROS 2's tools watch a mission at the pace of a flight.
            real_time: self.recording.ros2.is_some(),
            ..SimOptions::default()
        }
    }

    /// The world as the arguments describe it, with `seed`.
    pub(crate) fn world(&self, seed: u64) -> WorldOptions {
        WorldOptions {
            path: self.path,
            wind_speed_m_s: self.wind_m_s,
            wind_kind: if self.dryden {
                WindKind::Dryden
            } else {
                WindKind::Gusts
            },
            platform_speed_m_s: self.platform_speed_m_s,
            meeting_point_ne_m: self.meeting_point_ne_m,
            seed,
            realism: if self.ideal {
                Realism::ideal()
            } else {
                Realism::default()
            },
        }
    }

    /// Seeds to fly: of a plain run, or per cell of the hazard and path evaluations (1 unless
    /// --runs says otherwise; --evaluate has its own default).
    pub(crate) fn runs(&self) -> usize {
        self.runs.unwrap_or(1)
    }
}

/// Exit status when the mission did not land on the pad (or no run of many did).
pub const EXIT_NOT_LANDED: u8 = 4;
