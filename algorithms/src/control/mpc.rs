//! A horizontal MPC landing controller on clarabel (issue 6, item 3).
//!
//! Per horizontal axis (north, east; both in one QP, block diagonal) the state is the UAV's
//! position relative to the pad and the UAV's velocity. The UAV is the autopilot's velocity loop
//! seen from outside, a first-order lag with time constant τ (as in
//! [`point_mass`](super::point_mass)), discretised exactly for setpoints held over a step `dt`:
//!
//! ```text
//! v[k+1] = α·v[k] + (1 − α)·u[k],              α = exp(−dt/τ)
//! p[k+1] = p[k] + (dt − β)·u[k] + β·v[k],      β = τ·(1 − α)
//! ```
//!
//! The pad moves with its velocity and acceleration extrapolated over the horizon (the
//! acceleration held for at most `platform_accel_horizon_s`). The decision variables are the
//! corrections `d[k] = u[k] − v_platform[k]`, so the output is `v_uav = v_platform + v_ctrl` per
//! axis like the PID's, and the effort term penalises the correction, not the total speed.
//!
//! Cost: `Σ w_k·e[k]² + r·Σ d[k]² + s·Σ (u[k] − u[k−1])²` with `e` the position error at steps
//! 1..N (`w` = `terminal_position_weight` at N), `u[−1]` the previous command. Constraints per
//! axis and step: `|u[k]| ≤ max_speed_m_s`, `|u[k] − u[k−1]| ≤ max_accel_m_s2·dt` (clarabel's
//! nonnegative cone on `b − A·x`). The problem is condensed (positions eliminated), so `P` and
//! `A` depend on the configuration only; each step only `q` and `b` change.
//!
//! **Warm start.** clarabel 0.11 is an interior-point solver and has no primal/dual warm start.
//! What is reused is the solver object: it is set up once (equilibration, KKT structure and
//! symbolic factorisation) and each step only overwrites `q` and `b` (`update_q`, `update_b`;
//! presolve is disabled so updates are always allowed). The time bound is clarabel's
//! `time_limit` and `max_iter`. On a time-out, iteration limit or any other failure the step
//! returns a named [`MpcError`] carrying a safe fallback: the platform's velocity, clamped to the
//! speed limit and rate-limited from the previous command.
//!
//! The controller must be stepped every `dt_s` (the model's step is the control period), so
//! the rate limit on the plan is the rate limit on the commands.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};
use nalgebra::{DMatrix, DVector, Vector2};
use std::sync::Arc;
use std::time::Instant;
use thiserror::Error;

/// Errors from the MPC's configuration, its input, or one solve.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum MpcError {
    #[error("MPC {name} = {value} is invalid: {why}")]
    InvalidConfig {
        name: &'static str,
        value: f64,
        why: &'static str,
    },
    #[error("MPC input {name} is not finite; every input must be a finite number")]
    NonFinite { name: &'static str },
    #[error("MPC solver setup failed: {0}")]
    Setup(#[source] SolverSetupError),
    #[error("MPC solver setup failed: clarabel refuses data updates")]
    DataUpdatesRefused,
    /// clarabel stopped at `time_limit`; the fallback velocity should be flown.
    #[error("MPC solve hit its time limit of {limit_s} s; fallback {fallback_ne_m_s:?} m/s")]
    TimeLimit {
        limit_s: f64,
        fallback_ne_m_s: Vector2<f64>,
    },
    /// clarabel stopped at `max_iter`; the fallback velocity should be flown.
    #[error(
        "MPC solve hit its limit of {max_iterations} iterations; fallback {fallback_ne_m_s:?} m/s"
    )]
    IterationLimit {
        max_iterations: u32,
        fallback_ne_m_s: Vector2<f64>,
    },
    /// Any other non-solved status (numerical error, infeasible, ...).
    #[error("MPC solver failed ({status}); fallback {fallback_ne_m_s:?} m/s")]
    SolverFailed {
        status: String,
        fallback_ne_m_s: Vector2<f64>,
    },
}

/// clarabel's error at setup (its settings or its problem data). Shared, so that [`MpcError`]
/// stays `Clone`; clarabel's errors cannot be compared, so one equals only itself.
#[derive(Debug, Clone, Error)]
#[error(transparent)]
pub struct SolverSetupError(Arc<dyn std::error::Error + Send + Sync>);

impl SolverSetupError {
    fn new(error: impl std::error::Error + Send + Sync + 'static) -> Self {
        Self(Arc::new(error))
    }
}

impl PartialEq for SolverSetupError {
    fn eq(&self, other: &Self) -> bool {
        Arc::ptr_eq(&self.0, &other.0)
    }
}

impl MpcError {
    /// The velocity to fly when the solve failed (`None` for configuration and input errors).
    pub fn fallback_ne_m_s(&self) -> Option<Vector2<f64>> {
        match self {
            MpcError::TimeLimit {
                fallback_ne_m_s, ..
            }
            | MpcError::IterationLimit {
                fallback_ne_m_s, ..
            }
            | MpcError::SolverFailed {
                fallback_ne_m_s, ..
            } => Some(*fallback_ne_m_s),
            _ => None,
        }
    }
}

/// The MPC's configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MpcConfig {
    /// Number of steps N in the horizon.
    pub horizon_steps: usize,
    /// The model's step, which is also the control period.
    pub dt_s: f64,
    /// Time constant of the autopilot's velocity loop (the point mass's default is 0.2 s).
    pub velocity_time_constant_s: f64,
    /// Per-axis limit on the commanded velocity (total, platform included).
    pub max_speed_m_s: f64,
    /// Per-axis limit on the commanded velocity's rate of change.
    pub max_accel_m_s2: f64,
    /// Weight on the squared position error at steps 1..N−1, 1/(m²).
    pub position_weight: f64,
    /// Weight on the squared position error at step N.
    pub terminal_position_weight: f64,
    /// Weight on the squared correction `v_ctrl`, per (m/s)².
    pub effort_weight: f64,
    /// Weight on the squared setpoint change between steps, per (m/s)².
    pub rate_weight: f64,
    /// The platform's acceleration is extrapolated for at most this long, then held at the
    /// velocity reached (a turning tractor's acceleration rotates).
    pub platform_accel_horizon_s: f64,
    /// clarabel's `time_limit` for one solve.
    pub solve_time_limit_s: f64,
    /// clarabel's `max_iter` for one solve.
    pub max_iterations: u32,
}

impl Default for MpcConfig {
    fn default() -> Self {
        Self {
            horizon_steps: 20,
            dt_s: 0.05,
            velocity_time_constant_s: 0.2,
            max_speed_m_s: 6.0,
            // Per axis; the norm stays under the point mass's 3 m/s².
            max_accel_m_s2: 2.0,
            position_weight: 1.0,
            terminal_position_weight: 10.0,
            effort_weight: 0.05,
            rate_weight: 0.5,
            platform_accel_horizon_s: 0.5,
            solve_time_limit_s: 0.005,
            max_iterations: 50,
        }
    }
}

impl MpcConfig {
    /// Checks every number; called by [`MpcController::new`].
    pub fn validate(&self) -> Result<(), MpcError> {
        if self.horizon_steps == 0 || self.horizon_steps > 500 {
            return Err(MpcError::InvalidConfig {
                name: "horizon_steps",
                value: self.horizon_steps as f64,
                why: "must be in 1..=500",
            });
        }
        for (name, value) in [
            ("dt_s", self.dt_s),
            ("velocity_time_constant_s", self.velocity_time_constant_s),
            ("max_speed_m_s", self.max_speed_m_s),
            ("max_accel_m_s2", self.max_accel_m_s2),
            ("solve_time_limit_s", self.solve_time_limit_s),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(MpcError::InvalidConfig {
                    name,
                    value,
                    why: "must be a finite number > 0",
                });
            }
        }
        for (name, value) in [
            ("position_weight", self.position_weight),
            ("terminal_position_weight", self.terminal_position_weight),
            ("effort_weight", self.effort_weight),
            ("rate_weight", self.rate_weight),
            ("platform_accel_horizon_s", self.platform_accel_horizon_s),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(MpcError::InvalidConfig {
                    name,
                    value,
                    why: "must be a finite number ≥ 0",
                });
            }
        }
        if self.effort_weight + self.rate_weight <= 0.0 {
            return Err(MpcError::InvalidConfig {
                name: "effort_weight",
                value: self.effort_weight,
                why: "effort_weight + rate_weight must be > 0 (strictly convex QP)",
            });
        }
        if self.max_iterations == 0 {
            return Err(MpcError::InvalidConfig {
                name: "max_iterations",
                value: 0.0,
                why: "must be ≥ 1",
            });
        }
        Ok(())
    }

    fn alpha_beta(&self) -> (f64, f64) {
        let alpha = (-self.dt_s / self.velocity_time_constant_s).exp();
        (alpha, self.velocity_time_constant_s * (1.0 - alpha))
    }

    fn weight(&self, step: usize) -> f64 {
        if step + 1 == self.horizon_steps {
            self.terminal_position_weight
        } else {
            self.position_weight
        }
    }

    /// The platform's predicted velocity at `k·dt` on one axis.
    fn platform_velocity(&self, v0: f64, a0: f64, k: usize) -> f64 {
        v0 + a0 * (k as f64 * self.dt_s).min(self.platform_accel_horizon_s)
    }
}

/// One step's input (NE, world frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MpcInput {
    /// Measured horizontal position of the UAV relative to the pad centre (uav − pad).
    pub uav_minus_pad_ne_m: Vector2<f64>,
    /// Wanted position of the UAV relative to the pad centre (normally zero).
    pub setpoint_ne_m: Vector2<f64>,
    /// The UAV's velocity from the autopilot.
    pub uav_velocity_ne_m_s: Vector2<f64>,
    /// The platform's estimated velocity.
    pub platform_velocity_ne_m_s: Vector2<f64>,
    /// The platform's estimated acceleration (zero if unknown).
    pub platform_accel_ne_m_s2: Vector2<f64>,
}

/// One step's output.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MpcOutput {
    /// `v_uav = v_platform + v_ctrl`, the first setpoint of the plan.
    pub velocity_ne_m_s: Vector2<f64>,
    /// `v_ctrl` alone.
    pub ctrl_velocity_ne_m_s: Vector2<f64>,
    /// clarabel's iterations.
    pub iterations: u32,
    /// Wall time of the data update and the solve.
    pub solve_time_s: f64,
}

/// The MPC: one clarabel solver, set up once, updated and re-solved every step.
pub struct MpcController {
    config: MpcConfig,
    solver: DefaultSolver<f64>,
    /// Position error at steps 1..N per unit correction at step j (N×N, lower triangular).
    g: DMatrix<f64>,
    /// The command of the previous step; `None` before the first.
    previous_command: Option<Vector2<f64>>,
    /// The last successful plan: absolute velocity setpoints, NE, N of them.
    plan: Vec<Vector2<f64>>,
    q: Vec<f64>,
    b: Vec<f64>,
}

impl MpcController {
    pub fn new(config: MpcConfig) -> Result<Self, MpcError> {
        config.validate()?;
        let n = config.horizon_steps;
        let g = sensitivity(&config);
        let h = hessian(&config, &g);

        // P: block diagonal (north, east), upper triangle, every entry stored so the sparsity
        // never changes.
        let mut colptr = vec![0];
        let mut rowval = Vec::new();
        let mut nzval = Vec::new();
        for axis in 0..2 {
            for j in 0..n {
                for i in 0..=j {
                    rowval.push(axis * n + i);
                    nzval.push(h[(i, j)]);
                }
                colptr.push(rowval.len());
            }
        }
        let p = CscMatrix::new(2 * n, 2 * n, colptr, rowval, nzval);

        // A, per axis 4N rows: [I; −I; D; −D] with D the first difference (D[0,0] = 1).
        let mut colptr = vec![0];
        let mut rowval = Vec::new();
        let mut nzval = Vec::new();
        for axis in 0..2 {
            let r0 = axis * 4 * n;
            for j in 0..n {
                let mut push = |row: usize, value: f64| {
                    rowval.push(r0 + row);
                    nzval.push(value);
                };
                push(j, 1.0);
                push(n + j, -1.0);
                push(2 * n + j, 1.0);
                if j + 1 < n {
                    push(2 * n + j + 1, -1.0);
                }
                push(3 * n + j, -1.0);
                if j + 1 < n {
                    push(3 * n + j + 1, 1.0);
                }
                colptr.push(rowval.len());
            }
        }
        let a = CscMatrix::new(8 * n, 2 * n, colptr, rowval, nzval);

        let settings = DefaultSettingsBuilder::default()
            .verbose(false)
            .presolve_enable(false)
            .input_sparse_dropzeros(false)
            .time_limit(config.solve_time_limit_s)
            .max_iter(config.max_iterations)
            .build()
            .map_err(|e| MpcError::Setup(SolverSetupError::new(e)))?;
        let q = vec![0.0; 2 * n];
        // A feasible placeholder (all limits, zero offsets); overwritten before every solve.
        let mut b = vec![config.max_speed_m_s; 8 * n];
        for axis in 0..2 {
            for k in 2 * n..4 * n {
                b[axis * 4 * n + k] = config.max_accel_m_s2 * config.dt_s;
            }
        }
        let cones = [SupportedConeT::NonnegativeConeT(8 * n)];
        let solver = DefaultSolver::new(&p, &q, &a, &b, &cones, settings)
            .map_err(|e| MpcError::Setup(SolverSetupError::new(e)))?;
        if !solver.is_data_update_allowed() {
            return Err(MpcError::DataUpdatesRefused);
        }
        Ok(Self {
            config,
            solver,
            g,
            previous_command: None,
            plan: Vec::with_capacity(n),
            q,
            b,
        })
    }

    pub fn config(&self) -> &MpcConfig {
        &self.config
    }

    /// Forgets the previous command (the next step rate-limits from the UAV's velocity).
    pub fn reset(&mut self) {
        self.previous_command = None;
        self.plan.clear();
    }

    /// The last successful plan: N absolute velocity setpoints (NE), the first one commanded.
    pub fn plan(&self) -> &[Vector2<f64>] {
        &self.plan
    }

    /// One control step. Bad input is rejected and leaves the state untouched; a failed solve
    /// returns an error carrying the fallback command, which becomes the previous command.
    pub fn step(&mut self, input: &MpcInput) -> Result<MpcOutput, MpcError> {
        for (name, v) in [
            ("uav_minus_pad_ne_m", input.uav_minus_pad_ne_m),
            ("setpoint_ne_m", input.setpoint_ne_m),
            ("uav_velocity_ne_m_s", input.uav_velocity_ne_m_s),
            ("platform_velocity_ne_m_s", input.platform_velocity_ne_m_s),
            ("platform_accel_ne_m_s2", input.platform_accel_ne_m_s2),
        ] {
            if !v.iter().all(|x| x.is_finite()) {
                return Err(MpcError::NonFinite { name });
            }
        }
        let c = self.config;
        let n = c.horizon_steps;
        let v_max = c.max_speed_m_s;
        let du_max = c.max_accel_m_s2 * c.dt_s;
        let previous = self
            .previous_command
            .unwrap_or(input.uav_velocity_ne_m_s)
            .map(|x| x.clamp(-v_max, v_max));

        for axis in 0..2 {
            let e_free = free_response(
                &c,
                input.uav_minus_pad_ne_m[axis] - input.setpoint_ne_m[axis],
                input.uav_velocity_ne_m_s[axis],
                input.platform_velocity_ne_m_s[axis],
                input.platform_accel_ne_m_s2[axis],
            );
            let vp = |k: usize| {
                c.platform_velocity(
                    input.platform_velocity_ne_m_s[axis],
                    input.platform_accel_ne_m_s2[axis],
                    k,
                )
            };
            // f = Gᵀ·W·e_free + s·Dᵀ·c, with c[0] = vp[0] − u[−1], c[k] = vp[k] − vp[k−1].
            let offset = |k: usize| {
                if k == 0 {
                    vp(0) - previous[axis]
                } else {
                    vp(k) - vp(k - 1)
                }
            };
            for j in 0..n {
                let mut f = 0.0;
                for (k, e) in e_free.iter().enumerate().skip(j) {
                    f += self.g[(k, j)] * c.weight(k) * e;
                }
                let next = if j + 1 < n { offset(j + 1) } else { 0.0 };
                f += c.rate_weight * (offset(j) - next);
                self.q[axis * n + j] = f;
            }
            let r0 = axis * 4 * n;
            for k in 0..n {
                self.b[r0 + k] = v_max - vp(k);
                self.b[r0 + n + k] = v_max + vp(k);
                self.b[r0 + 2 * n + k] = du_max - offset(k);
                self.b[r0 + 3 * n + k] = du_max + offset(k);
            }
        }

        let started = Instant::now();
        let updated = self
            .solver
            .update_q(&self.q)
            .and_then(|()| self.solver.update_b(&self.b));
        if let Err(e) = updated {
            return Err(self.fail(input, previous, format!("data update: {e}")));
        }
        self.solver.solve();
        let solve_time_s = started.elapsed().as_secs_f64();
        let solution = &self.solver.solution;
        match solution.status {
            SolverStatus::Solved | SolverStatus::AlmostSolved => {}
            SolverStatus::MaxTime => {
                let fallback = self.fallback(input, previous);
                return Err(MpcError::TimeLimit {
                    limit_s: c.solve_time_limit_s,
                    fallback_ne_m_s: fallback,
                });
            }
            SolverStatus::MaxIterations => {
                let fallback = self.fallback(input, previous);
                return Err(MpcError::IterationLimit {
                    max_iterations: c.max_iterations,
                    fallback_ne_m_s: fallback,
                });
            }
            status => return Err(self.fail(input, previous, format!("{status:?}"))),
        }
        let iterations = solution.iterations;
        self.plan.clear();
        for k in 0..n {
            let vp = Vector2::new(
                c.platform_velocity(
                    input.platform_velocity_ne_m_s.x,
                    input.platform_accel_ne_m_s2.x,
                    k,
                ),
                c.platform_velocity(
                    input.platform_velocity_ne_m_s.y,
                    input.platform_accel_ne_m_s2.y,
                    k,
                ),
            );
            self.plan
                .push(vp + Vector2::new(solution.x[k], solution.x[n + k]));
        }
        // The interior point is feasible to ~1e-8; clamp so the command is exactly inside.
        let command = self.plan[0].zip_map(&previous, |u, prev| {
            u.clamp(prev - du_max, prev + du_max).clamp(-v_max, v_max)
        });
        self.previous_command = Some(command);
        Ok(MpcOutput {
            velocity_ne_m_s: command,
            ctrl_velocity_ne_m_s: command - input.platform_velocity_ne_m_s,
            iterations,
            solve_time_s,
        })
    }

    /// The fallback command: the previous plan's next setpoint when the previous step solved
    /// (clarabel has no warm start, so the old plan is the only prior solution there is), else
    /// the platform's velocity; clamped to the speed limit and rate-limited from the previous
    /// command either way. It becomes the previous command and the old plan is dropped, so a
    /// second failure in a row falls back to the platform's velocity.
    fn fallback(&mut self, input: &MpcInput, previous: Vector2<f64>) -> Vector2<f64> {
        let du_max = self.config.max_accel_m_s2 * self.config.dt_s;
        let v_max = self.config.max_speed_m_s;
        let target = self
            .plan
            .get(1)
            .copied()
            .unwrap_or(input.platform_velocity_ne_m_s);
        let command = target.zip_map(&previous, |u, prev| {
            u.clamp(prev - du_max, prev + du_max).clamp(-v_max, v_max)
        });
        self.previous_command = Some(command);
        self.plan.clear();
        command
    }

    fn fail(&mut self, input: &MpcInput, previous: Vector2<f64>, status: String) -> MpcError {
        MpcError::SolverFailed {
            status,
            fallback_ne_m_s: self.fallback(input, previous),
        }
    }
}

/// G[k, j]: the position error at step k+1 per unit of the correction at step j.
fn sensitivity(c: &MpcConfig) -> DMatrix<f64> {
    let n = c.horizon_steps;
    let (alpha, beta) = c.alpha_beta();
    let mut g = DMatrix::zeros(n, n);
    let mut e = DVector::<f64>::zeros(n);
    let mut v = DVector::<f64>::zeros(n);
    for k in 0..n {
        e += &v * beta;
        e[k] += c.dt_s - beta;
        v *= alpha;
        v[k] += 1.0 - alpha;
        g.row_mut(k).copy_from(&e.transpose());
    }
    g
}

/// H = Gᵀ·W·G + r·I + s·DᵀD (the QP's ½xᵀHx per axis).
fn hessian(c: &MpcConfig, g: &DMatrix<f64>) -> DMatrix<f64> {
    let n = c.horizon_steps;
    let w = DMatrix::from_diagonal(&DVector::from_fn(n, |k, _| c.weight(k)));
    let mut d = DMatrix::<f64>::identity(n, n);
    for k in 1..n {
        d[(k, k - 1)] = -1.0;
    }
    g.transpose() * w * g
        + DMatrix::<f64>::identity(n, n) * c.effort_weight
        + d.transpose() * d * c.rate_weight
}

/// The position error at steps 1..N with zero correction (the UAV commanded the platform's
/// predicted velocity).
fn free_response(c: &MpcConfig, e0: f64, v0: f64, vp0: f64, ap0: f64) -> Vec<f64> {
    let (alpha, beta) = c.alpha_beta();
    let mut e = e0;
    let mut v = v0;
    (0..c.horizon_steps)
        .map(|k| {
            let u = c.platform_velocity(vp0, ap0, k);
            let pad = 0.5 * c.dt_s * (u + c.platform_velocity(vp0, ap0, k + 1));
            e += (c.dt_s - beta) * u + beta * v - pad;
            v = alpha * v + (1.0 - alpha) * u;
            e
        })
        .collect()
}

#[cfg(test)]
mod tests;
