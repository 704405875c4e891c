//! Time of one tracker step (predict at 50 Hz + a 10 fps vision fix, delay-compensated) and one
//! two-stage PID step, against textbook baselines in the same run: the same Kalman equations on
//! heap-allocated dynamic matrices, and a bare PID without anti-windup, filter or gain stages;
//! and one MPC step (data update + clarabel solve) at the default horizon.
//!
//! `cargo bench -p algorithms --bench estimation_control`

use std::hint::black_box;

use algorithms::control::mpc::{MpcConfig, MpcController, MpcInput};
use algorithms::control::pid::{HorizontalPid, PidConfig, PidInput};
use algorithms::estimation::kalman::{MotionInput, Tracker, TrackerConfig, VisionFix};
use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{DMatrix, DVector, Matrix3, Vector2, Vector3};

fn kalman(c: &mut Criterion) {
    let input = MotionInput {
        uav_velocity_ned_m_s: Vector3::new(3.0, 0.2, 0.0),
        uav_acceleration_ned_m_s2: Vector3::zeros(),
        platform_velocity_ned_m_s: Vector3::new(2.9, 0.1, 0.0),
    };
    let mut group = c.benchmark_group("kalman");
    group.sample_size(30);
    group.measurement_time(std::time::Duration::from_secs(3));
    // Five predictions (50 Hz) and one fix captured 40 ms earlier (10 fps, delayed).
    group.bench_function("tracker: 5 predicts + 1 delayed fix", |b| {
        let mut tracker = Tracker::new(TrackerConfig::default()).expect("config");
        let mut time_s = 0.0;
        tracker
            .correct(&VisionFix {
                capture_time_s: 0.0,
                uav_relative_ned_m: Vector3::new(1.0, -0.5, -7.5),
                covariance_m2: Matrix3::identity() * 0.02,
            })
            .expect("first fix");
        b.iter(|| {
            for _ in 0..5 {
                time_s += 0.02;
                tracker.predict(time_s, black_box(&input)).expect("predict");
            }
            let fix = VisionFix {
                capture_time_s: time_s - 0.04,
                uav_relative_ned_m: Vector3::new(1.0, -0.5, -7.5),
                covariance_m2: Matrix3::identity() * 0.02,
            };
            tracker.correct(black_box(&fix)).expect("fix")
        })
    });
    group.bench_function("baseline: dynamic-matrix KF, 5 predicts + 1 fix", |b| {
        let mut x = DVector::from_vec(vec![1.0, -0.5, -7.5]);
        let mut p = DMatrix::<f64>::identity(3, 3);
        let q = DMatrix::<f64>::identity(3, 3) * 0.02 * 0.05;
        let r = DMatrix::<f64>::identity(3, 3) * 0.02;
        let h = DMatrix::<f64>::identity(3, 3);
        let f = DMatrix::<f64>::identity(3, 3);
        let u = DVector::from_vec(vec![0.1 * 0.02, 0.1 * 0.02, 0.0]);
        let z = DVector::from_vec(vec![1.0, -0.5, -7.5]);
        b.iter(|| {
            for _ in 0..5 {
                x = &f * &x + &u;
                p = &f * &p * f.transpose() + &q;
            }
            let e = &z - &h * &x;
            let s = &h * &p * h.transpose() + &r;
            let k = &p * h.transpose() * s.try_inverse().expect("invertible");
            x += &k * e;
            p = (DMatrix::<f64>::identity(3, 3) - &k * &h) * &p;
            black_box(&x);
        })
    });
    group.finish();
}

fn pid(c: &mut Criterion) {
    let mut group = c.benchmark_group("pid");
    group.sample_size(30);
    group.measurement_time(std::time::Duration::from_secs(3));
    group.bench_function("two-stage PID step (both axes)", |b| {
        let mut pid = HorizontalPid::new(PidConfig::default()).expect("config");
        let mut t = 0.0_f64;
        b.iter(|| {
            t += 0.05;
            let input = PidInput {
                dt_s: 0.05,
                height_m: 5.0,
                uav_minus_pad_ne_m: Vector2::new(t.sin(), t.cos()),
                setpoint_ne_m: Vector2::zeros(),
                platform_velocity_ne_m_s: Vector2::new(3.0, 0.0),
            };
            pid.step(black_box(&input)).expect("step")
        })
    });
    group.bench_function("baseline: bare PID step (both axes)", |b| {
        let (kp, ki, kd, dt) = (0.8, 0.0, 0.35, 0.05);
        let mut integral = [0.0_f64; 2];
        let mut previous = [0.0_f64; 2];
        let mut t = 0.0_f64;
        b.iter(|| {
            t += 0.05;
            let error = [-t.sin(), -t.cos()];
            let mut out = [0.0; 2];
            for axis in 0..2 {
                integral[axis] += error[axis] * dt;
                out[axis] = 3.0 * (1 - axis) as f64
                    + kp * error[axis]
                    + ki * integral[axis]
                    + kd * (error[axis] - previous[axis]) / dt;
                previous[axis] = error[axis];
            }
            black_box(out)
        })
    });
    group.finish();
}

fn mpc(c: &mut Criterion) {
    let mut group = c.benchmark_group("mpc");
    group.sample_size(20);
    group.measurement_time(std::time::Duration::from_secs(5));
    // The default horizon (20 steps of 50 ms); the pad circles the vehicle so constraints
    // come and go as in flight. The PID step above is the baseline a landing loop could use.
    group.bench_function("MPC step, horizon 20", |b| {
        let mut mpc = MpcController::new(MpcConfig {
            solve_time_limit_s: 1.0,
            ..MpcConfig::default()
        })
        .expect("config");
        let mut t = 0.0_f64;
        b.iter(|| {
            t += 0.05;
            let input = MpcInput {
                uav_minus_pad_ne_m: Vector2::new(2.0 * t.sin(), 2.0 * t.cos()),
                setpoint_ne_m: Vector2::zeros(),
                uav_velocity_ne_m_s: Vector2::new(3.0, 0.0),
                platform_velocity_ne_m_s: Vector2::new(3.0 * t.cos(), 3.0 * t.sin()),
                platform_accel_ne_m_s2: Vector2::new(-0.5 * t.sin(), 0.5 * t.cos()),
            };
            mpc.step(black_box(&input)).expect("solve")
        })
    });
    group.finish();
}

criterion_group!(benches, kalman, pid, mpc);
criterion_main!(benches);
