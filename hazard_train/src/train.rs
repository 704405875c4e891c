//! The training loop: shuffled mini-batches of random crops, Adam with a short warm-up and a
//! cosine decay of the learning rate, everything seeded.

use std::time::Instant;

use algorithms::vision::render::SplitMix64;
use candle_core::Device;
use candle_nn::{AdamW, Optimizer, ParamsAdamW};
use thiserror::Error;

use crate::dataset::{batch, CropConfig, Sample, SetError};
use crate::model::{HazardNet, Mode, ModelError};
use crate::target::{loss, LossWeights, TargetError};

#[derive(Debug, Error)]
pub enum TrainError {
    #[error("training needs at least one sample")]
    NoSamples,
    #[error("`{name}` must be positive and finite, got {value}")]
    Setting { name: &'static str, value: f64 },
    #[error("the loss became {value} at epoch {epoch}, step {step}: lower the learning rate")]
    Diverged {
        epoch: usize,
        step: usize,
        value: f32,
    },
    #[error(transparent)]
    Set(#[from] SetError),
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(transparent)]
    Target(#[from] TargetError),
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

/// How to train.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TrainConfig {
    pub epochs: usize,
    pub batch_size: usize,
    pub crop: CropConfig,
    pub learning_rate: f64,
    /// Steps of linear warm-up from a tenth of the rate.
    pub warmup_steps: usize,
    /// The cosine decay ends at this fraction of the rate.
    pub final_rate_fraction: f64,
    pub loss_weights: LossWeights,
    /// Shuffling and crops.
    pub seed: u64,
}

/// Mean losses of one epoch and how long it took.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct EpochReport {
    pub epoch: usize,
    pub loss: f64,
    pub objectness: f64,
    pub centre: f64,
    pub size: f64,
    pub class: f64,
    pub learning_rate: f64,
    pub seconds: f64,
}

impl TrainConfig {
    fn validate(&self) -> Result<(), TrainError> {
        for (name, value) in [
            ("epochs", self.epochs as f64),
            ("batch_size", self.batch_size as f64),
            ("learning_rate", self.learning_rate),
            ("final_rate_fraction", self.final_rate_fraction),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(TrainError::Setting { name, value });
            }
        }
        self.crop.validate()?;
        Ok(())
    }

    /// The learning rate at `step` of `total_steps`.
    pub fn rate_at(&self, step: usize, total_steps: usize) -> f64 {
        if step < self.warmup_steps {
            let t = step as f64 / self.warmup_steps as f64;
            return self.learning_rate * (0.1 + 0.9 * t);
        }
        let span = total_steps.saturating_sub(self.warmup_steps).max(1) as f64;
        let t = ((step - self.warmup_steps) as f64 / span).min(1.0);
        let floor = self.final_rate_fraction;
        self.learning_rate
            * (floor + (1.0 - floor) * 0.5 * (1.0 + (std::f64::consts::PI * t).cos()))
    }
}

/// Trains `net` in place on `samples`; `on_epoch` hears each epoch's report.
pub fn train(
    net: &HazardNet,
    samples: &[Sample],
    config: &TrainConfig,
    device: &Device,
    on_epoch: &mut dyn FnMut(&EpochReport),
) -> Result<Vec<EpochReport>, TrainError> {
    config.validate()?;
    if samples.is_empty() {
        return Err(TrainError::NoSamples);
    }
    let mut optimiser = AdamW::new(
        net.vars(),
        ParamsAdamW {
            lr: config.learning_rate,
            weight_decay: 0.0,
            ..Default::default()
        },
    )?;
    let mut rng = SplitMix64::new(config.seed ^ 0x0074_7261_696e);
    let steps_per_epoch = samples.len().div_ceil(config.batch_size);
    let total_steps = steps_per_epoch * config.epochs;
    let mut order: Vec<usize> = (0..samples.len()).collect();
    let mut reports = Vec::with_capacity(config.epochs);
    for epoch in 0..config.epochs {
        let started = Instant::now();
        shuffle(&mut order, &mut rng);
        let mut sums = [0f64; 5];
        let mut rate = config.learning_rate;
        for (step_in_epoch, indices) in order.chunks(config.batch_size).enumerate() {
            let step = epoch * steps_per_epoch + step_in_epoch;
            rate = config.rate_at(step, total_steps);
            optimiser.set_learning_rate(rate);
            let (images, targets) = batch(
                samples,
                indices,
                &config.crop,
                net.config.anchor_px,
                &mut rng,
                device,
            )?;
            let raw = net.raw(&images, Mode::Train)?;
            let parts = loss(&raw, &targets, &config.loss_weights)?;
            let value = parts.total.to_scalar::<f32>()?;
            if !value.is_finite() {
                return Err(TrainError::Diverged {
                    epoch,
                    step: step_in_epoch,
                    value,
                });
            }
            optimiser.backward_step(&parts.total)?;
            for (sum, part) in sums.iter_mut().zip([
                value,
                parts.objectness,
                parts.centre,
                parts.size,
                parts.class,
            ]) {
                *sum += part as f64;
            }
        }
        let mean = |k: usize| sums[k] / steps_per_epoch as f64;
        let report = EpochReport {
            epoch,
            loss: mean(0),
            objectness: mean(1),
            centre: mean(2),
            size: mean(3),
            class: mean(4),
            learning_rate: rate,
            seconds: started.elapsed().as_secs_f64(),
        };
        on_epoch(&report);
        reports.push(report);
    }
    Ok(reports)
}

/// Fisher–Yates with the crate's seeded generator.
fn shuffle(order: &mut [usize], rng: &mut SplitMix64) {
    for i in (1..order.len()).rev() {
        let j = (rng.next_u64() % (i as u64 + 1)) as usize;
        order.swap(i, j);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::NetConfig;

    #[test]
    fn a_few_steps_on_a_tiny_batch_lower_the_loss() {
        let device = Device::Cpu;
        let samples: Vec<Sample> = [3u64, 4]
            .into_iter()
            .map(|seed| Sample::render(seed).unwrap().0)
            .collect();
        assert!(samples.iter().map(|s| s.boxes.len()).sum::<usize>() >= 2);
        let net = HazardNet::new(
            NetConfig::with_widths([8, 8, 16, 16, 16, 16, 16]),
            5,
            &device,
        )
        .unwrap();
        let config = TrainConfig {
            epochs: 25,
            batch_size: 2,
            crop: CropConfig {
                width_px: 320,
                height_px: 240,
                flips: false,
            },
            learning_rate: 3e-3,
            warmup_steps: 0,
            final_rate_fraction: 1.0,
            loss_weights: LossWeights::default(),
            seed: 1,
        };
        // Whole frames, no flips: every step sees the same batch, so the loss must fall.
        let measure = |net: &HazardNet| {
            let mut rng = SplitMix64::new(0);
            let (images, targets) =
                batch(&samples, &[0, 1], &config.crop, 32.0, &mut rng, &device).unwrap();
            let raw = net.raw(&images, Mode::Train).unwrap();
            loss(&raw, &targets, &config.loss_weights)
                .unwrap()
                .total
                .to_scalar::<f32>()
                .unwrap()
        };
        let before = measure(&net);
        let mut epochs = 0;
        train(&net, &samples, &config, &device, &mut |_| epochs += 1).unwrap();
        let after = measure(&net);
        assert_eq!(epochs, 25);
        assert!(after < 0.5 * before, "loss {before} → {after}");
    }

    #[test]
    fn the_rate_warms_up_then_decays_to_its_floor() {
        let config = TrainConfig {
            epochs: 1,
            batch_size: 1,
            crop: CropConfig {
                width_px: 16,
                height_px: 16,
                flips: false,
            },
            learning_rate: 1e-3,
            warmup_steps: 10,
            final_rate_fraction: 0.05,
            loss_weights: LossWeights::default(),
            seed: 0,
        };
        assert!((config.rate_at(0, 110) - 1e-4).abs() < 1e-12);
        assert!((config.rate_at(5, 110) - 5.5e-4).abs() < 1e-12);
        assert!((config.rate_at(10, 110) - 1e-3).abs() < 1e-12);
        // Half way through the cosine: the mean of the rate and its floor.
        assert!((config.rate_at(60, 110) - 0.525e-3).abs() < 1e-12);
        assert!((config.rate_at(110, 110) - 0.05e-3).abs() < 1e-12);
        let bad = TrainConfig {
            learning_rate: f64::NAN,
            ..config
        };
        let net = HazardNet::new(NetConfig::with_widths([2; 7]), 0, &Device::Cpu).unwrap();
        assert!(matches!(
            train(&net, &[], &bad, &Device::Cpu, &mut |_| {}),
            Err(TrainError::Setting {
                name: "learning_rate",
                ..
            })
        ));
    }
}
