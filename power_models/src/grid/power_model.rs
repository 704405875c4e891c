//! Power as a function of the QoS knobs: one joint grid, or a base plus one grid per task.

use super::{Evaluation, GridModel, ModelError, MAX_DIMS, MAX_MODEL_KNOBS};

/// Computation power as a function of the QoS knobs.
#[derive(Debug, Clone, PartialEq)]
pub enum PowerModel {
    /// One grid over all knobs of coupled tasks (e.g. tasks sharing the GPU); its values are
    /// the board's total power.
    Joint(GridModel),
    /// `base_power_w + Σ parts`: each part is one task's model of the power it adds ABOVE the
    /// base load (board idle with the mission software loaded), not its measured total. Build
    /// a part from a task's profile with `GridModel::from_profile(..)?.shifted(-base_power_w)`.
    Additive {
        base_power_w: f64,
        parts: Vec<GridModel>,
    },
}

impl PowerModel {
    /// An additive model, checked: a finite base and at most [`MAX_MODEL_KNOBS`] knobs.
    pub fn additive(base_power_w: f64, parts: Vec<GridModel>) -> Result<PowerModel, ModelError> {
        if !base_power_w.is_finite() {
            return Err(ModelError::BadBasePower(base_power_w));
        }
        let model = PowerModel::Additive {
            base_power_w,
            parts,
        };
        let count = model.knob_names().len();
        if count > MAX_MODEL_KNOBS {
            return Err(ModelError::TooManyModelKnobs(count));
        }
        Ok(model)
    }

    /// The knobs a query gives values for, in order: the joint grid's knobs, or the parts'
    /// knobs in part order with a knob shared by several parts listed once, where it first
    /// appears.
    pub fn knob_names(&self) -> Vec<&str> {
        match self {
            PowerModel::Joint(g) => g.knob_names().iter().map(String::as_str).collect(),
            PowerModel::Additive { parts, .. } => {
                let mut names: Vec<&str> = Vec::new();
                for name in parts.iter().flat_map(|p| p.knob_names()) {
                    if !names.contains(&name.as_str()) {
                        names.push(name);
                    }
                }
                names
            }
        }
    }

    /// Predicted power at `x`, given in [`PowerModel::knob_names`] order.
    ///
    /// # Panics
    /// When `x` is shorter than the model's knob list, or a hand-built `Additive` has more
    /// than [`MAX_MODEL_KNOBS`] knobs; [`PowerModel::try_eval`] checks both.
    pub fn eval(&self, x: &[f64]) -> Evaluation {
        match self {
            PowerModel::Joint(g) => g.eval(x),
            PowerModel::Additive {
                base_power_w,
                parts,
            } => {
                // Union positions are recomputed by name on each call, so no lookup table has
                // to live in the enum; it costs a few short string comparisons, no allocation.
                let mut seen: [&str; MAX_MODEL_KNOBS] = [""; MAX_MODEL_KNOBS];
                let mut count = 0usize;
                let mut value = *base_power_w;
                let mut clamped = 0u64;
                for part in parts {
                    let mut sub = [0.0f64; MAX_DIMS];
                    let mut pos = [0usize; MAX_DIMS];
                    for (j, name) in part.knob_names().iter().enumerate() {
                        let u = match seen[..count].iter().position(|s| *s == name.as_str()) {
                            Some(u) => u,
                            None => {
                                seen[count] = name;
                                count += 1;
                                count - 1
                            }
                        };
                        pos[j] = u;
                        sub[j] = x[u];
                    }
                    let e = part.eval(&sub[..part.dims()]);
                    value += e.value;
                    for (j, &u) in pos.iter().enumerate().take(part.dims()) {
                        if e.is_clamped(j) {
                            clamped |= 1 << u;
                        }
                    }
                }
                Evaluation {
                    value,
                    extrapolated: clamped != 0,
                    clamped,
                }
            }
        }
    }

    /// [`PowerModel::eval`] with the query checked: length, no NaN, knob count.
    pub fn try_eval(&self, x: &[f64]) -> Result<Evaluation, ModelError> {
        let names = self.knob_names();
        if names.len() > MAX_MODEL_KNOBS {
            return Err(ModelError::TooManyModelKnobs(names.len()));
        }
        if x.len() != names.len() {
            return Err(ModelError::QueryDimension {
                got: x.len(),
                expected: names.len(),
            });
        }
        if let Some(k) = x.iter().position(|v| v.is_nan()) {
            return Err(ModelError::QueryNaN {
                knob: names[k].to_string(),
            });
        }
        Ok(self.eval(x))
    }
}
