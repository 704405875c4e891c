//! The evaluation's table and CSV, one row per cell.

use super::*;

/// One line of the table: a cell and its runs' statistics.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Row {
    pub world: World,
    pub rate_fps: f64,
    pub wind_m_s: f64,
    pub wind_kind: WindModel,
    pub path: String,
    pub tractor_speed_m_s: f64,
    pub runs: usize,
    pub success_rate: f64,
    pub touchdown_error_p50_m: Option<f64>,
    pub touchdown_error_p95_m: Option<f64>,
    pub time_to_land_p50_s: Option<f64>,
    pub touchdown_vertical_speed_p95_m_s: Option<f64>,
    pub touchdown_tilt_p95_deg: Option<f64>,
    pub blind_before_contact_p95_s: Option<f64>,
    pub energy_mean_wh: f64,
    pub companion_energy_mean_wh: f64,
    pub landing_aborts_mean: f64,
}

impl Row {
    pub fn of(cell: &Cell, runs: &[RunRecord]) -> Self {
        let outcomes: Vec<SimOutcome> = runs.iter().map(RunRecord::outcome).collect();
        let summary = SimSummary::of(&outcomes);
        let aborts: u64 = runs.iter().map(|r| u64::from(r.landing_aborts)).sum();
        Self {
            world: cell.world,
            rate_fps: cell.rate_fps,
            wind_m_s: cell.wind_m_s,
            wind_kind: cell.wind_kind,
            path: cell.path.to_string(),
            tractor_speed_m_s: cell.tractor_speed_m_s,
            runs: summary.runs,
            success_rate: summary.success_rate,
            touchdown_error_p50_m: summary.touchdown_error_p50_m,
            touchdown_error_p95_m: summary.touchdown_error_p95_m,
            time_to_land_p50_s: summary.time_to_land_p50_s,
            touchdown_vertical_speed_p95_m_s: summary.touchdown_vertical_speed_p95_m_s,
            touchdown_tilt_p95_deg: summary.touchdown_tilt_p95_deg,
            blind_before_contact_p95_s: summary.blind_before_contact_p95_s,
            energy_mean_wh: summary.energy_mean_wh,
            companion_energy_mean_wh: summary.companion_energy_mean_wh,
            landing_aborts_mean: if runs.is_empty() {
                0.0
            } else {
                aborts as f64 / runs.len() as f64
            },
        }
    }
}

pub fn rows(merged: &Merged) -> Vec<Row> {
    merged
        .evaluation
        .cells
        .iter()
        .zip(&merged.runs)
        .map(|(cell, runs)| Row::of(cell, runs))
        .collect()
}

/// The table, for people.
pub fn table(evaluation: &Evaluation, rows: &[Row]) -> String {
    let seeds = match (evaluation.seeds.first(), evaluation.seeds.last()) {
        (Some(first), Some(last)) => format!(
            "{} per cell ({first}..={last})",
            plural(evaluation.seeds.len(), "seed")
        ),
        _ => "no seeds".into(),
    };
    let mut out = format!(
        "{seeds}, {} s of tracking, {}, config {}, autopilot {}\n\n",
        evaluation.tracking_s,
        plural(evaluation.cells.len(), "cell"),
        evaluation.config_path,
        evaluation.autopilot
    );
    out += "| autopilot | world | marker rate (fps) | wind (m/s) | wind kind | path | tractor (m/s) | success | touchdown error p50 / p95 (m) | vertical speed p95 (m/s) | tilt p95 (°) | blind before contact p95 (s) | time to land p50 (s) | energy (Wh) | of which companion (Wh) | landing aborts (mean) |\n";
    out += "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n";
    let metres = |v: Option<f64>| v.map_or_else(|| "—".into(), |v| format!("{v:.3}"));
    let hundredths = |v: Option<f64>| v.map_or_else(|| "—".into(), |v| format!("{v:.2}"));
    let tenths = |v: Option<f64>| v.map_or_else(|| "—".into(), |v| format!("{v:.1}"));
    for r in rows {
        out += &format!(
            "| {} | {} | {} | {} | {} | {} | {} | {:.0} %{} | {} / {} | {} | {} | {} | {} | {:.2} | {:.3} | {:.2} |\n",
            evaluation.autopilot,
            r.world,
            r.rate_fps,
            r.wind_m_s,
            r.wind_kind.name(),
            r.path,
            r.tractor_speed_m_s,
            100.0 * r.success_rate,
            // A partial merge's cell: over the runs it has, marked.
            if r.runs < evaluation.seeds.len() {
                format!(" (partial: {} of {} runs)", r.runs, evaluation.seeds.len())
            } else {
                String::new()
            },
            metres(r.touchdown_error_p50_m),
            metres(r.touchdown_error_p95_m),
            hundredths(r.touchdown_vertical_speed_p95_m_s),
            tenths(r.touchdown_tilt_p95_deg),
            hundredths(r.blind_before_contact_p95_s),
            tenths(r.time_to_land_p50_s),
            r.energy_mean_wh,
            r.companion_energy_mean_wh,
            r.landing_aborts_mean
        );
    }
    out
}

/// The CSV columns, one row per cell.
pub const CSV_HEADER: &str = "autopilot,world,rate_fps,wind_m_s,wind_kind,path,tractor_speed_m_s,runs,success_rate,touchdown_error_p50_m,touchdown_error_p95_m,touchdown_vertical_speed_p95_m_s,touchdown_tilt_p95_deg,blind_before_contact_p95_s,time_to_land_p50_s,energy_mean_wh,companion_energy_mean_wh,landing_aborts_mean";

/// The table as CSV (RFC 4180): a header line, then one row per cell; numbers in full
/// precision, a statistic with no runs to it empty.
pub fn csv(autopilot: &str, rows: &[Row]) -> String {
    let number = |v: f64| v.to_string();
    let optional = |v: Option<f64>| v.map_or_else(String::new, |v| v.to_string());
    let mut out = format!("{CSV_HEADER}\r\n");
    for r in rows {
        let fields = [
            autopilot.to_string(),
            r.world.to_string(),
            number(r.rate_fps),
            number(r.wind_m_s),
            r.wind_kind.name().to_string(),
            r.path.clone(),
            number(r.tractor_speed_m_s),
            r.runs.to_string(),
            number(r.success_rate),
            optional(r.touchdown_error_p50_m),
            optional(r.touchdown_error_p95_m),
            optional(r.touchdown_vertical_speed_p95_m_s),
            optional(r.touchdown_tilt_p95_deg),
            optional(r.blind_before_contact_p95_s),
            optional(r.time_to_land_p50_s),
            number(r.energy_mean_wh),
            number(r.companion_energy_mean_wh),
            number(r.landing_aborts_mean),
        ];
        let fields: Vec<String> = fields.iter().map(|f| csv_field(f)).collect();
        out += &fields.join(",");
        out += "\r\n";
    }
    out
}

/// A CSV field: quoted, its quotes doubled, when it holds a comma, a quote or a line break.
pub fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
}
