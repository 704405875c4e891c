//! The bad configs `qosrt check` must reject: each a change to the reference mission, and where
//! each diagnostic must point.

/// Where a diagnostic must point: the `occurrence`-th (0-based) match of `marker`, or 1:1.
pub struct Expect {
    pub marker: Option<(&'static str, usize)>,
    pub message: &'static str,
}

pub struct BadCase {
    pub name: &'static str,
    pub replace: &'static [(&'static str, &'static str)],
    pub expect: &'static [Expect],
}

const fn at(marker: &'static str, occurrence: usize, message: &'static str) -> Expect {
    Expect {
        marker: Some((marker, occurrence)),
        message,
    }
}

const fn at_start(message: &'static str) -> Expect {
    Expect {
        marker: None,
        message,
    }
}

pub const BAD_CASES: &[BadCase] = &[
    BadCase {
        name: "a phase kind that is none of transit, track, land",
        replace: &[("kind = \"land\"", "kind = \"landing\"")],
        expect: &[at(
            "\"landing\"",
            1,
            "unknown value `landing`; did you mean `land`?; expected one of: transit, track, land",
        )],
    },
    BadCase {
        name: "a landing phase before the last",
        replace: &[("kind = \"track\"", "kind = \"land\"")],
        expect: &[at(
            "\"land\"",
            1,
            "phase `tracking` is of kind `land`, but a land phase must come last (the mission ends at touchdown)",
        )],
    },
    BadCase {
        name: "trigger on an input the task does not read",
        replace: &[(
            "trigger = \"input:vision/landing_marker\"",
            "trigger = \"input:vision/landing_markers\"",
        )],
        expect: &[at(
            "\"input:vision/landing_markers\"",
            0,
            "task `tracking` is triggered by `vision/landing_markers`, which it does not read; did you mean `vision/landing_marker`?; its inputs: vehicle/state, vision/landing_marker",
        )],
    },
    BadCase {
        name: "trigger that is neither period nor input",
        replace: &[("trigger = \"input:camera/frame\"", "trigger = \"frame\"")],
        expect: &[at(
            "\"frame\"",
            0,
            "trigger `frame`: expected `period` or `input:TOPIC`",
        )],
    },
    BadCase {
        name: "idle time on a periodic task",
        replace: &[(
            "trigger = \"input:tracking/relative_state\"",
            "trigger = \"period\"",
        )],
        expect: &[at(
            "50.0              # ...and on its own",
            0,
            "task `landing` runs on its period; `max_idle_ms` only applies with `trigger = \"input:TOPIC\"`",
        )],
    },
    BadCase {
        name: "misspelt key",
        replace: &[("name = \"tractor-landing\"", "naem = \"tractor-landing\"")],
        expect: &[at("naem", 0, "unknown key `naem` in [mission]; did you mean `name`?")],
    },
    BadCase {
        name: "string where a number belongs",
        replace: &[("reserve_fraction = 0.25", "reserve_fraction = \"a\"")],
        expect: &[at("\"a\"", 0, "expected a number")],
    },
    BadCase {
        name: "negative cell count",
        replace: &[("cell_count = 4 ", "cell_count = -4 ")],
        expect: &[at("-4", 0, "expected a whole number ≥ 0")],
    },
    BadCase {
        name: "misspelt section",
        replace: &[("[battery]", "[batery]")],
        expect: &[
            at_start("missing section [battery]"),
            at("batery", 0, "unknown section `batery`; did you mean `battery`?"),
        ],
    },
    BadCase {
        name: "unknown resource",
        replace: &[("resource = \"gpu\"", "resource = \"gpux\"")],
        expect: &[at("\"gpux\"", 0, "unknown value `gpux`; did you mean `gpu`?")],
    },
    BadCase {
        name: "missing key",
        replace: &[("reserve_fraction = 0.25", "")],
        expect: &[at("[mission]", 0, "missing key `reserve_fraction` in [mission]")],
    },
    BadCase {
        name: "not TOML",
        replace: &[("hover_power_w = 165.0", "hover_power_w = 165.0 =")],
        expect: &[at("=\n", 0, "invalid TOML")],
    },
    BadCase {
        name: "reserve of the whole battery",
        replace: &[("reserve_fraction = 0.25", "reserve_fraction = 1.0")],
        expect: &[at("1.0\n", 0, "reserve_fraction must be within [0, 1)")],
    },
    BadCase {
        name: "two tasks on the GPU",
        replace: &[(
            "[task.params]\nclasses",
            "[task.params]\nclasses = []\n\n[[task]]\nname = \"hazard2\"\nplugin = \"hazard_cnn\"\nresource = \"gpu\"\nphases = [\"tracking\"]\nweight = 1.0\nknob = \"rate_fps\"\nlevels = [1.0]\nutility = [1.0]\n\n[task.params]\nclassez",
        )],
        expect: &[at(
            "\"gpu\"",
            2,
            "task `hazard2` claims the GPU, but task `hazard` already holds it",
        )],
    },
    BadCase {
        name: "rates out of order",
        replace: &[("levels = [0.5, 1.0, 2.0, 10.0]", "levels = [0.5, 2.0, 1.0, 10.0]")],
        expect: &[at(
            "1.0, 10.0]",
            0,
            "rate_fps must be strictly increasing: 1 is not greater than 2",
        )],
    },
    BadCase {
        name: "duplicate level",
        replace: &[("levels = [0.5, 1.0, 2.0, 10.0]", "levels = [0.5, 1.0, 1.0, 10.0]")],
        expect: &[at("1.0, 10.0]", 0, "level 1 rate_fps is listed twice")],
    },
    BadCase {
        name: "periods out of order",
        replace: &[("levels = [100.0, 50.0, 20.0]    # the tracking", "levels = [20.0, 50.0, 100.0]    # the tracking")],
        expect: &[at(
            "50.0, 100.0]",
            0,
            "period_ms must be strictly decreasing: 50 is not less than 20",
        ), at("100.0]", 0, "period_ms must be strictly decreasing: 100 is not less than 50")],
    },
    BadCase {
        name: "no levels",
        replace: &[
            ("levels = [0.1, 0.25, 1.0, 4.0]", "levels = []"),
            ("utility = [0.2, 0.4, 0.75, 1.0]", "utility = []"),
        ],
        expect: &[at("[]", 0, "a task needs at least one QoS level")],
    },
    BadCase {
        name: "utility above one",
        replace: &[("utility = [0.2, 0.4, 0.75, 1.0]", "utility = [0.2, 0.4, 0.75, 1.5]")],
        expect: &[at("1.5]", 0, "a utility must be within [0, 1], found 1.5")],
    },
    BadCase {
        name: "utility decreasing",
        replace: &[("utility = [0.1, 0.3, 0.5, 1.0]", "utility = [0.1, 0.6, 0.5, 1.0]")],
        expect: &[at("0.5, 1.0]", 0, "utilities must not decrease with QoS: 0.5 follows 0.6")],
    },
    BadCase {
        name: "utility count",
        replace: &[("utility = [0.5, 0.8, 1.0]", "utility = [0.5, 1.0]")],
        expect: &[at("[0.5, 1.0]", 0, "expected one utility per level (3), found 2")],
    },
    BadCase {
        name: "zero rate",
        replace: &[("levels = [0.1, 0.25, 1.0, 4.0]", "levels = [0.0, 0.25, 1.0, 4.0]")],
        expect: &[at("0.0, 0.25", 0, "rate_fps must be a finite number > 0, found 0")],
    },
    BadCase {
        name: "unknown phase",
        replace: &[("phases = [\"tracking\", \"landing\"]\nweight = 1.5", "phases = [\"tracking\", \"landin\"]\nweight = 1.5")],
        expect: &[at("\"landin\"", 0, "unknown phase `landin`; did you mean `landing`?")],
    },
    BadCase {
        name: "unknown plugin",
        replace: &[("plugin = \"landing_marker\"", "plugin = \"landing_markr\"")],
        expect: &[at(
            "\"landing_markr\"",
            0,
            "unknown plugin `landing_markr`; did you mean `landing_marker`?",
        )],
    },
    BadCase {
        name: "duplicate task",
        replace: &[("name = \"landing\"\nplugin", "name = \"tracking\"\nplugin")],
        expect: &[at("\"tracking\"\nplugin = \"landing_guidance\"", 0, "task `tracking` is defined twice")],
    },
    BadCase {
        name: "a camera with no frames",
        replace: &[("rate_fps = 10.0\n# The downward", "rate_fps = -10.0\n# The downward")],
        expect: &[at(
            "-10.0",
            0,
            "the camera's rate_fps must be a finite number > 0, found -10",
        )],
    },
    BadCase {
        name: "misspelt camera key",
        replace: &[("rate_fps = 10.0\n# The downward", "rate_fsp = 10.0\n# The downward")],
        expect: &[at(
            "rate_fsp",
            0,
            "unknown key `rate_fsp` in [camera]; did you mean `rate_fps`?",
        )],
    },
    BadCase {
        name: "a camera with no field of view",
        replace: &[("horizontal_fov_deg = 60.0", "horizontal_fov_deg = 0.0")],
        expect: &[at(
            "0.0\nwidth_px",
            0,
            "the camera's horizontal_fov_deg must be within (0, 180), found 0",
        )],
    },
    BadCase {
        name: "a camera mount that is neither",
        replace: &[("mount = \"gimbal\"", "mount = \"tripod\"")],
        expect: &[at("\"tripod\"", 0, "`tripod`")],
    },
    BadCase {
        name: "a task that describes the camera itself",
        replace: &[(
            "fix_angle_std_deg = 1.7 ",
            "camera_horizontal_fov_deg = 70.0\nfix_angle_std_deg = 1.7 ",
        )],
        expect: &[at(
            "70.0\nfix_angle",
            0,
            "the camera is described once, in [camera]: write `horizontal_fov_deg = …` there \
             instead of `camera_horizontal_fov_deg` in task `tracking`'s params",
        )],
    },
    BadCase {
        name: "a frame policy that is neither",
        replace: &[("[camera]\n", "[record]\nframes = \"half\"\n\n[camera]\n")],
        expect: &[at("\"half\"", 0, "`half`")],
    },
    BadCase {
        name: "a frame codec that is not one",
        replace: &[("[camera]\n", "[record]\ncodec = \"jpeg\"\n\n[camera]\n")],
        expect: &[at("\"jpeg\"", 0, "`jpeg`")],
    },
    BadCase {
        name: "a size budget of nothing",
        replace: &[("[camera]\n", "[record]\nmax_mb = 0\n\n[camera]\n")],
        expect: &[at("0\n\n[camera]", 0, "nonzero")],
    },
    BadCase {
        name: "negative phase duration",
        replace: &[("duration_s = 900.0", "duration_s = -900.0")],
        expect: &[at("-900.0", 0, "duration_s must be a finite number > 0, found -900")],
    },
    BadCase {
        name: "missing profile",
        replace: &[("jetson-nano-seed/landing.toml", "jetson-nano-seed/nothere.toml")],
        expect: &[at("\"/", 1, "nothere.toml` not found")],
    },
    BadCase {
        name: "capacity twice",
        replace: &[("capacity_mah = 5000.0", "capacity_mah = 5000.0\ncapacity_wh = 74.0")],
        expect: &[at("5000.0", 0, "either `capacity_wh` or `capacity_mah`, not both")],
    },
    BadCase {
        name: "no capacity",
        replace: &[("capacity_mah = 5000.0", "")],
        expect: &[at("[battery]", 0, "the battery needs its capacity")],
    },
    BadCase {
        name: "durations per level miscounted",
        replace: &[("duration_s = [90.0, 80.0, 70.0, 60.0]", "duration_s = [90.0, 60.0]")],
        expect: &[at("[90.0, 60.0]", 0, "expected 4 durations, one per level of task `detection`, found 2")],
    },
    BadCase {
        name: "durations per level of an unknown task",
        replace: &[("task = \"detection\", duration_s", "task = \"detectoin\", duration_s")],
        expect: &[at("\"detectoin\"", 0, "unknown task `detectoin`; did you mean `detection`?")],
    },
    BadCase {
        name: "cores on the GPU task",
        replace: &[("resource = \"gpu\"", "resource = \"gpu\"\ncores = [0]")],
        expect: &[at("[0]", 0, "a GPU task takes none")],
    },
    BadCase {
        name: "flight power of an unknown phase",
        replace: &[("tracking = 175.0", "trackng = 175.0")],
        expect: &[at("175.0", 0, "unknown phase `trackng`; did you mean `tracking`?")],
    },
    BadCase {
        name: "zero cells",
        replace: &[("cell_count = 4 ", "cell_count = 0 ")],
        expect: &[at("0                  # cells", 0, "cell_count must be between 1 and 24")],
    },
    BadCase {
        name: "pack voltage given per cell",
        replace: &[("nominal_cell_voltage_v = 3.7", "nominal_cell_voltage_v = 14.8")],
        expect: &[at("14.8", 0, "nominal_cell_voltage_v is per cell")],
    },
    BadCase {
        name: "negative weight",
        replace: &[("weight = 1.5", "weight = -1.5")],
        expect: &[at("-1.5", 0, "weight must be a finite number ≥ 0, found -1.5")],
    },
    BadCase {
        name: "a misspelt array of tables",
        replace: &[
            ("[[task]]\nname = \"hazard\"", "[[tasks]]\nname = \"hazard\""),
            ("[task.params]\nclasses", "[tasks.params]\nclasses"),
        ],
        expect: &[at(
            "tasks]]",
            0,
            "unknown section `tasks`; did you mean `task`?",
        )],
    },
    BadCase {
        name: "a phase no profile models",
        replace: &[(
            "phases = [\"transit\", \"tracking\"]\n",
            "phases = [\"tracking\"]\n",
        )],
        expect: &[at(
            "[[power_model.profile]]",
            0,
            "no profile models phase `transit`",
        )],
    },
    BadCase {
        name: "two profiles for a phase without the idle power",
        replace: &[("phases = [\"landing\"]\n", "phases = [\"landing\", \"tracking\"]\n")],
        expect: &[at(
            "[power_model]\n",
            0,
            "phase `tracking` is modelled by 2 profiles, which add up only above the board's idle power: set `idle_power_w`",
        )],
    },
    BadCase {
        name: "pack resistance in milliohms",
        replace: &[("internal_resistance_ohm = 0.025", "internal_resistance_ohm = 25")],
        expect: &[at("25 #", 0, "internal_resistance_ohm is the whole pack's, in ohms")],
    },
    BadCase {
        name: "a governor setting out of range",
        replace: &[("replan_period_s = 10.0", "replan_period_s = -10.0")],
        expect: &[at("-10.0", 0, "governor config: replan_period_s = -10 is invalid")],
    },
    BadCase {
        name: "a misspelt governor setting",
        replace: &[("min_dwell_s = 60.0", "min_dwel_s = 60.0")],
        expect: &[at(
            "min_dwel_s",
            0,
            "unknown key `min_dwel_s` in [governor]; did you mean `min_dwell_s`?",
        )],
    },
    BadCase {
        name: "a misspelt link setting",
        replace: &[("\n[governor]", "\n[link]\nsigning_key_fil = \"key.bin\"\n\n[governor]")],
        expect: &[at(
            "signing_key_fil",
            0,
            "unknown key `signing_key_fil` in [link]; did you mean `signing_key_file`?",
        )],
    },
    BadCase {
        name: "every mistake is listed, not only the first",
        replace: &[
            ("reserve_fraction = 0.25", "reserve_fraction = 2.5"),
            ("cell_count = 4 ", "cell_count = 0 "),
            ("utility = [0.2, 0.4, 0.75, 1.0]", "utility = [0.2, 0.4, 0.75, 1.5]"),
        ],
        expect: &[
            at("2.5", 0, "reserve_fraction must be within [0, 1)"),
            at("0                  # cells", 0, "cell_count must be between 1 and 24"),
            at("1.5]", 0, "a utility must be within [0, 1]"),
        ],
    },
];
