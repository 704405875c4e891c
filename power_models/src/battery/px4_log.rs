//! PX4's `battery_status` topic, exported from a ULog to CSV, read into rows the estimator
//! takes.

use super::{BatteryError, BatterySample};

/// One row of a PX4 ULog `battery_status` topic exported to CSV (pyulog's `ulog2csv`).
/// Columns newer PX4 versions dropped (`voltage_filtered_v`, `current_filtered_a`) or added
/// later are optional.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Px4BatteryRow {
    pub timestamp_us: u64,
    pub voltage_v: f64,
    pub voltage_filtered_v: Option<f64>,
    pub current_a: f64,
    pub current_filtered_a: Option<f64>,
    pub discharged_mah: f64,
    pub remaining: f64,
    pub scale: Option<f64>,
    pub cell_count: Option<u32>,
    pub connected: Option<bool>,
    pub warning: Option<u32>,
}

impl Px4BatteryRow {
    /// Timestamp in seconds.
    pub fn time_s(&self) -> f64 {
        self.timestamp_us as f64 * 1e-6
    }

    /// The row as the estimator's sample. PX4's "unknown" markers become None: a voltage of 0
    /// or less (no battery), a negative current, discharged charge or remaining (-1).
    /// Non-finite values pass through, so the estimator reports them.
    pub fn to_sample(&self) -> BatterySample {
        // NaN is kept (and reported by the estimator), only PX4's sentinels are dropped.
        let known_if = |v: f64, known: bool| (known || v.is_nan()).then_some(v);
        BatterySample {
            time_s: self.time_s(),
            voltage_v: known_if(self.voltage_v, self.voltage_v > 0.0),
            current_a: known_if(self.current_a, self.current_a >= 0.0),
            consumed_mah: known_if(self.discharged_mah, self.discharged_mah >= 0.0),
            remaining_fraction: known_if(self.remaining, self.remaining >= 0.0),
        }
    }
}

/// Parses the CSV of a PX4 `battery_status` topic, finding columns by their header names
/// (any order, extra columns ignored). Required: `timestamp` (µs, integer), `voltage_v`,
/// `current_a`, `discharged_mah`, `remaining`. Blank lines are skipped; `nan` parses as NaN.
/// Line numbers in errors count the header as line 1.
pub fn parse_px4_battery_csv(text: &str) -> Result<Vec<Px4BatteryRow>, BatteryError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim_end_matches('\r')))
        .filter(|(_, l)| !l.trim().is_empty());
    let (_, header) = lines.next().ok_or(BatteryError::CsvEmpty)?;
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let find = |name: &str| names.iter().position(|&n| n == name);
    let require =
        |name: &'static str| find(name).ok_or(BatteryError::CsvMissingColumn { column: name });
    let c_timestamp = require("timestamp")?;
    let c_voltage = require("voltage_v")?;
    let c_current = require("current_a")?;
    let c_discharged = require("discharged_mah")?;
    let c_remaining = require("remaining")?;
    let c_voltage_f = find("voltage_filtered_v");
    let c_current_f = find("current_filtered_a");
    let c_scale = find("scale");
    let c_cells = find("cell_count");
    let c_connected = find("connected");
    let c_warning = find("warning");

    let mut rows = Vec::new();
    for (line, text) in lines {
        let fields: Vec<&str> = text.split(',').map(str::trim).collect();
        if fields.len() != names.len() {
            return Err(BatteryError::CsvFieldCount {
                line,
                expected: names.len(),
                found: fields.len(),
            });
        }
        let bad = |col: usize, expected: &'static str| BatteryError::CsvBadValue {
            line,
            column: names[col].to_string(),
            text: fields[col].to_string(),
            expected,
        };
        let float = |col: usize| fields[col].parse::<f64>().map_err(|_| bad(col, "a number"));
        let unsigned = |col: usize| {
            fields[col]
                .parse::<u32>()
                .map_err(|_| bad(col, "a non-negative integer"))
        };
        let opt_float = |col: Option<usize>| col.map(float).transpose();
        let connected = match c_connected {
            None => None,
            Some(col) => Some(match fields[col] {
                "1" | "true" | "True" => true,
                "0" | "false" | "False" => false,
                _ => return Err(bad(col, "a boolean (0/1/true/false)")),
            }),
        };
        rows.push(Px4BatteryRow {
            timestamp_us: fields[c_timestamp]
                .parse::<u64>()
                .map_err(|_| bad(c_timestamp, "a timestamp in integer microseconds"))?,
            voltage_v: float(c_voltage)?,
            voltage_filtered_v: opt_float(c_voltage_f)?,
            current_a: float(c_current)?,
            current_filtered_a: opt_float(c_current_f)?,
            discharged_mah: float(c_discharged)?,
            remaining: float(c_remaining)?,
            scale: opt_float(c_scale)?,
            cell_count: c_cells.map(unsigned).transpose()?,
            connected,
            warning: c_warning.map(unsigned).transpose()?,
        });
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::battery::{BatteryEstimate, BatteryEstimator, BatterySpec, OcvCurve};

    // ---- PX4 CSV ------------------------------------------------------------------------

    const CSV_HEADER: &str = "timestamp,voltage_v,voltage_filtered_v,current_a,current_filtered_a,discharged_mah,remaining,scale,cell_count,connected,warning";

    #[test]
    fn csv_parses_by_column_name() {
        let text = format!(
            "{CSV_HEADER}\r\n226493702,14.002368,15.776365,33.366684,20.161938,24.618793,0.91272706,1.0171117,4,1,0\r\n\n\
             226793719,13.794987,15.381584,-1,25.297806,27.37938,0.8928354,1.021094,4,0,2\n"
        );
        let rows = parse_px4_battery_csv(&text).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0].timestamp_us, 226_493_702);
        assert_eq!(rows[0].voltage_v, 14.002368);
        assert_eq!(rows[0].voltage_filtered_v, Some(15.776365));
        assert_eq!(rows[0].cell_count, Some(4));
        assert_eq!(rows[1].connected, Some(false));
        assert_eq!(rows[1].warning, Some(2));
        let s = rows[1].to_sample();
        assert_eq!(s.current_a, None, "PX4's -1 means unknown");
        assert_eq!(s.voltage_v, Some(13.794987));
        assert!((s.time_s - 226.793719).abs() < 1e-9);

        // Another column order, optional columns absent.
        let rows = parse_px4_battery_csv(
            "remaining,current_a,timestamp,discharged_mah,voltage_v\n0.5,3.0,1000000,12.5,15.9\n",
        )
        .unwrap();
        assert_eq!(rows[0].remaining, 0.5);
        assert_eq!(rows[0].voltage_filtered_v, None);
        assert_eq!(rows[0].connected, None);
    }

    #[test]
    fn csv_errors_name_the_column_and_line() {
        assert_eq!(parse_px4_battery_csv(""), Err(BatteryError::CsvEmpty));
        assert_eq!(
            parse_px4_battery_csv("timestamp,voltage_v,current_a,remaining\n"),
            Err(BatteryError::CsvMissingColumn {
                column: "discharged_mah"
            })
        );
        let text = format!("{CSV_HEADER}\n1,15,15,3,3,1,0.9,1,4,1,0\n2,15,15,3x,3,1,0.9,1,4,1,0\n");
        match parse_px4_battery_csv(&text) {
            Err(BatteryError::CsvBadValue {
                line, column, text, ..
            }) => {
                assert_eq!(
                    (line, column.as_str(), text.as_str()),
                    (3, "current_a", "3x")
                );
            }
            other => panic!("{other:?}"),
        }
        let text = format!("{CSV_HEADER}\n1.5,15,15,3,3,1,0.9,1,4,1,0\n");
        assert!(matches!(
            parse_px4_battery_csv(&text),
            Err(BatteryError::CsvBadValue { line: 2, .. })
        ));
        let text = format!("{CSV_HEADER}\n1,15,15,3,3,1,0.9,1,4,maybe,0\n");
        assert!(matches!(
            parse_px4_battery_csv(&text),
            Err(BatteryError::CsvBadValue { .. })
        ));
        let text = format!("{CSV_HEADER}\n1,15,15,3\n");
        assert_eq!(
            parse_px4_battery_csv(&text),
            Err(BatteryError::CsvFieldCount {
                line: 2,
                expected: 11,
                found: 4
            })
        );
        let msg = BatteryError::CsvMissingColumn {
            column: "remaining",
        }
        .to_string();
        assert!(msg.contains("remaining"));
    }

    // ---- the real PX4 flight log --------------------------------------------------------------

    fn px4_log_rows() -> Option<Vec<Px4BatteryRow>> {
        let rel = "data/px4-flight-battery/battery_status.csv";
        let candidates = [
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../shared")
                .join(rel),
            std::path::Path::new("/work/shared").join(rel),
        ];
        for path in &candidates {
            if let Ok(text) = std::fs::read_to_string(path) {
                return Some(parse_px4_battery_csv(&text).unwrap());
            }
        }
        eprintln!("skipped: the PX4 flight log is absent (looked for {candidates:?})");
        None
    }

    /// Capacity and resistance from the log's own voltage and current, without `remaining`:
    /// for each trial R, read SoC from the OCV curve at (V + I·R)/n and regress it on
    /// discharged_mah; the slope is −1/C and the R with the smallest residual wins.
    /// Returns (capacity mAh, R Ω, residual).
    fn fit_capacity_and_resistance(rows: &[Px4BatteryRow], cells: f64) -> (f64, f64, f64) {
        let curve = OcvCurve::lipo();
        let mut best = (f64::NAN, f64::NAN, f64::INFINITY);
        for k in 0..=60 {
            let r = k as f64 * 0.0025;
            let pts: Vec<(f64, f64)> = rows
                .iter()
                .map(|row| {
                    (
                        row.discharged_mah,
                        curve.soc_at_cell_ocv_v((row.voltage_v + row.current_a * r) / cells),
                    )
                })
                .collect();
            let n = pts.len() as f64;
            let (mx, my) = (
                pts.iter().map(|p| p.0).sum::<f64>() / n,
                pts.iter().map(|p| p.1).sum::<f64>() / n,
            );
            let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
            let sxx: f64 = pts.iter().map(|p| (p.0 - mx) * (p.0 - mx)).sum();
            let slope = sxy / sxx;
            let resid = (pts
                .iter()
                .map(|p| (p.1 - my - slope * (p.0 - mx)).powi(2))
                .sum::<f64>()
                / n)
                .sqrt();
            if resid < best.2 {
                best = (-1.0 / slope, r, resid);
            }
        }
        best
    }

    /// Capacity from the drop of PX4's `remaining` against discharged_mah, between the first
    /// and the last 30 % of the in-flight stretch where `remaining` is no longer clipped at 1,
    /// comparing rows at the same load (median current ± 1 A) so PX4's load compensation,
    /// which inflates `remaining` in flight, cancels.
    fn capacity_from_remaining_drop(rows: &[Px4BatteryRow], landing: usize) -> f64 {
        let last_clipped = rows[..landing]
            .iter()
            .rposition(|r| r.remaining >= 0.9999)
            .unwrap_or(0);
        let span = &rows[last_clipped..landing];
        let mut currents: Vec<f64> = span.iter().map(|r| r.current_a).collect();
        currents.sort_by(f64::total_cmp);
        let median = currents[currents.len() / 2];
        let (t0, t1) = (span[0].time_s(), span[span.len() - 1].time_s());
        let mean_of = |lo: f64, hi: f64| {
            let sel: Vec<&Px4BatteryRow> = span
                .iter()
                .filter(|r| {
                    r.time_s() >= lo && r.time_s() < hi && (r.current_a - median).abs() <= 1.0
                })
                .collect();
            let n = sel.len() as f64;
            (
                sel.iter().map(|r| r.discharged_mah).sum::<f64>() / n,
                sel.iter().map(|r| r.remaining).sum::<f64>() / n,
            )
        };
        let w = 0.3 * (t1 - t0);
        let (mah_a, rem_a) = mean_of(t0, t0 + w);
        let (mah_b, rem_b) = mean_of(t1 - w, t1 + 1.0);
        (mah_b - mah_a) / (rem_a - rem_b)
    }

    struct Px4Run {
        rows: Vec<Px4BatteryRow>,
        estimates: Vec<BatteryEstimate>,
        capacity_mah: f64,
        resistance_ohm: f64,
        capacity_from_remaining_mah: f64,
        landing: usize,
    }

    fn run_on_px4_log() -> Option<Px4Run> {
        let rows = px4_log_rows()?;
        let cells = rows[0].cell_count.unwrap_or(4);
        assert_eq!(cells, 4);
        // Landing: the last row drawing flight current (> 1 A); after it the pack rests.
        let landing = rows.iter().rposition(|r| r.current_a > 1.0).unwrap();
        let (capacity_mah, resistance_ohm, resid) =
            fit_capacity_and_resistance(&rows, f64::from(cells));
        let capacity_from_remaining_mah = capacity_from_remaining_drop(&rows, landing);
        eprintln!(
            "PX4 log: {} rows, {:.0} s; capacity fitted from V, I, discharged: {capacity_mah:.0} mAh, \
             R {resistance_ohm:.4} ohm (SoC residual {resid:.4}); from the drop of `remaining`: \
             {capacity_from_remaining_mah:.0} mAh",
            rows.len(),
            rows[rows.len() - 1].time_s() - rows[0].time_s()
        );
        let spec =
            BatterySpec::from_capacity_mah(capacity_mah, cells, 3.7, resistance_ohm).unwrap();
        let mut est = BatteryEstimator::new(spec).unwrap();
        let estimates = rows
            .iter()
            .map(|r| est.update(r.to_sample()).unwrap())
            .collect::<Vec<_>>();
        // PX4_TRACE=1 prints the run every 100 rows.
        if std::env::var_os("PX4_TRACE").is_some() {
            for (r, e) in rows.iter().zip(&estimates).step_by(100) {
                eprintln!("{:8.1} V {:6.3} I {:6.2} soc {:.4} sig {:.4} vsoc {:.4} rem {:.4} E {:.1} P {:.1}", r.time_s() - rows[0].time_s(), r.voltage_v, r.current_a, e.soc, e.soc_sigma, e.voltage_soc.unwrap_or(f64::NAN), r.remaining, e.remaining_energy_wh, e.power_w);
            }
        }
        Some(Px4Run {
            rows,
            estimates,
            capacity_mah,
            resistance_ohm,
            capacity_from_remaining_mah,
            landing,
        })
    }

    #[test]
    fn px4_log_coulomb_count_matches_discharged_mah() {
        let Some(run) = run_on_px4_log() else { return };
        let base = run.rows[0].discharged_mah;
        let total = run.rows[run.rows.len() - 1].discharged_mah - base;
        let (mut max_err, mut bound_sq) = (0.0_f64, 0.0);
        for (k, (row, e)) in run.rows.iter().zip(&run.estimates).enumerate() {
            max_err = max_err.max((e.consumed_mah - (row.discharged_mah - base)).abs());
            if k > 0 {
                let prev = &run.rows[k - 1];
                let dt = row.time_s() - prev.time_s();
                bound_sq += ((row.current_a - prev.current_a).abs() * dt / 2.0 / 3.6).powi(2);
            }
        }
        let final_err = run.estimates[run.estimates.len() - 1].consumed_mah - total;
        // PX4 integrates every sensor reading, the log keeps one every ~0.3 s. Within a step
        // the trapezoid cannot know the path; its error there is of the order of half the
        // current change times dt. Summed as independent errors that is `bound`; 3 bound
        // is the tolerance.
        let bound = 3.0 * bound_sq.sqrt();
        eprintln!(
            "PX4 log coulomb count: {:.2} mAh counted vs {total:.2} logged; final error \
             {final_err:+.3} mAh ({:+.4} %), max error {max_err:.3} mAh ({:.4} %); tolerance {bound:.2} mAh",
            run.estimates[run.estimates.len() - 1].consumed_mah,
            100.0 * final_err / total,
            100.0 * max_err / total,
        );
        assert!(final_err.abs() <= bound, "final {final_err} > {bound}");
        assert!(max_err <= bound, "max {max_err} > {bound}");
        assert!(
            bound < 0.005 * total,
            "the tolerance itself must stay small: {bound}"
        );
    }

    #[test]
    fn px4_log_soc_against_logged_remaining() {
        let Some(run) = run_on_px4_log() else { return };
        let Px4Run {
            rows,
            estimates,
            landing,
            ..
        } = &run;
        // The two capacity estimates come from independent data; they must roughly agree.
        let ratio = run.capacity_from_remaining_mah / run.capacity_mah;
        assert!(
            (0.75..=1.25).contains(&ratio),
            "capacities disagree: ratio {ratio}"
        );
        assert!(
            (0.03..=0.12).contains(&run.resistance_ohm),
            "R {}",
            run.resistance_ohm
        );

        let stats = |sel: &[usize]| {
            let errs: Vec<f64> = sel
                .iter()
                .map(|&k| estimates[k].soc - rows[k].remaining)
                .collect();
            let rms = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len() as f64).sqrt();
            let max = errs.iter().fold(0.0_f64, |m, e| m.max(e.abs()));
            let mean = errs.iter().sum::<f64>() / errs.len() as f64;
            (rms, max, mean, errs.len())
        };
        let all: Vec<usize> = (0..rows.len()).collect();
        let unclipped: Vec<usize> = (0..*landing)
            .filter(|&k| rows[k].remaining < 0.9999)
            .collect();
        // At rest after landing, 5 s on, when PX4's load compensation no longer inflates it.
        let t_land = rows[*landing].time_s();
        let rest: Vec<usize> = (*landing..rows.len())
            .filter(|&k| rows[k].time_s() > t_land + 5.0)
            .collect();
        let (rms_all, max_all, mean_all, n_all) = stats(&all);
        let (rms_unc, max_unc, mean_unc, n_unc) = stats(&unclipped);
        let (rms_rest, max_rest, mean_rest, n_rest) = stats(&rest);
        // How much PX4's in-flight compensation lifts `remaining`: its jump at landing, where
        // no charge is drawn (mean of the last 10 s of flight against the rest).
        let flight_tail: Vec<usize> = (0..*landing)
            .filter(|&k| rows[k].time_s() > t_land - 10.0)
            .collect();
        let mean_rem =
            |sel: &[usize]| sel.iter().map(|&k| rows[k].remaining).sum::<f64>() / sel.len() as f64;
        let inflation = mean_rem(&flight_tail) - mean_rem(&rest);
        // PX4 computes `scale = v_charged / (v_empty + (v_charged - v_empty)·soc_voltage)` from
        // its voltage-only SoC; if `remaining` is that SoC, 1/scale = r + a·(1 - r) holds with
        // one constant a = v_empty / v_charged on every row.
        let ratios: Vec<f64> = rows
            .iter()
            .filter(|r| r.remaining < 0.99)
            .filter_map(|r| Some((1.0 / r.scale? - r.remaining) / (1.0 - r.remaining)))
            .collect();
        let (a_min, a_max) = ratios
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &a| {
                (lo.min(a), hi.max(a))
            });
        let t_settled = rows[0].time_s() + 60.0;
        let settled = rows.iter().position(|r| r.time_s() >= t_settled).unwrap();
        let first = &estimates[settled];
        let last = &estimates[estimates.len() - 1];
        eprintln!(
            "PX4 log SoC (ours - remaining): all {n_all} rows RMS {rms_all:.3} max {max_all:.3} mean {mean_all:+.3}; \
             unclipped in flight {n_unc} rows RMS {rms_unc:.3} max {max_unc:.3} mean {mean_unc:+.3}; \
             at rest after landing {n_rest} rows RMS {rms_rest:.3} max {max_rest:.3} mean {mean_rest:+.3}; \
             `remaining` clipped at 1 in {} rows; its jump at landing {inflation:.3}; PX4 v_empty/v_charged \
             from `scale` {a_min:.5}..{a_max:.5} over {} rows; our SoC {:.3} (60 s) -> {:.3} \
             (sigma {:.3}), remaining {:.3} -> {:.3}; remaining energy at rest {:.1} Wh",
            rows.len() - rows.iter().filter(|r| r.remaining < 0.9999).count(),
            ratios.len(),
            first.soc,
            last.soc,
            last.soc_sigma,
            rows[0].remaining,
            rows[rows.len() - 1].remaining,
            last.remaining_energy_wh,
        );
        // So the reference is PX4's voltage-only estimate (no capacity configured: it also stays
        // at 1 while 1.6 Ah are drawn), a linear map of cell voltage between v_empty and
        // v_charged (ratio ~0.807, e.g. 3.35/4.15 V), lifted in flight by its throttle-based load
        // compensation and clipped at 1. It is not a true SoC, and the assertions say what
        // agreement that allows:
        // - at rest after landing, where the lift is (mostly) gone, the two voltage→SoC maps
        //   (linear vs LiPo curve) must agree within 0.1;
        // - in flight, ours sits below by about PX4's lift, which the log itself shows as the
        //   jump of `remaining` at landing (no charge drawn then), within 0.1;
        // - over the whole log the gap is that lift plus clipping: RMS 0.25, max 0.3.
        assert!(
            a_max - a_min < 1e-3,
            "remaining is not PX4's voltage estimate"
        );
        assert!(
            inflation > 0.05,
            "expected PX4's remaining to drop at landing: {inflation}"
        );
        assert!(max_rest < 0.1, "at rest: {max_rest}");
        assert!(
            mean_unc < 0.0,
            "ours should sit below the load-lifted reference: {mean_unc}"
        );
        assert!(
            (mean_unc.abs() - inflation).abs() < 0.1,
            "lift {inflation} vs mean gap {mean_unc}"
        );
        assert!(max_unc < inflation + 0.15, "{max_unc}");
        assert!(max_all < 0.3, "{max_all}");
        assert!(rms_all < 0.25, "{rms_all}");
        // After the first minute ours never steps up by more than voltage noise allows.
        let rises = estimates[settled..]
            .windows(2)
            .map(|w| w[1].soc - w[0].soc)
            .fold(0.0_f64, f64::max);
        assert!(rises < 0.01, "largest single-step rise {rises}");
    }
}
