//! Batch normalisation and the leaky ReLU after it, fused into one operation for training.
//! Written with candle's element-wise operations they took a dozen passes over every
//! activation, each allocating, and about 40 % of a training step; here the forward pass is
//! two passes per channel and the gradient three. Inference does not use this: the export folds
//! the normalisation into the convolution, and [`crate::model`] keeps the plain form for it.

use std::sync::{Arc, Mutex};

use candle_core::{CpuStorage, CustomOp3, Layout, Shape, Tensor};

/// The statistics of one batch, per channel: mean and biased variance.
#[derive(Debug, Clone, PartialEq)]
pub struct BatchStats {
    pub mean: Vec<f64>,
    pub var: Vec<f64>,
    /// Values per channel (batch × height × width).
    pub count: usize,
}

/// `leaky(scale · (x − μ) / √(σ² + ε) + shift)` per channel, μ and σ² over the batch.
struct NormLeaky {
    eps: f64,
    slope: f32,
    /// Where the forward pass leaves the batch's statistics (for the running averages).
    stats: Arc<Mutex<Option<BatchStats>>>,
}

fn contiguous<'a>(storage: &'a CpuStorage, layout: &Layout) -> candle_core::Result<&'a [f32]> {
    let Some((start, end)) = layout.contiguous_offsets() else {
        candle_core::bail!("the fused batch norm needs contiguous inputs")
    };
    Ok(&storage.as_slice::<f32>()?[start..end])
}

/// Mean and biased variance of one channel, accumulated in f64.
fn moments(values: &[f32]) -> (f64, f64) {
    let n = values.len().max(1) as f64;
    let mean = values.iter().map(|&v| v as f64).sum::<f64>() / n;
    let var = values
        .iter()
        .map(|&v| (v as f64 - mean).powi(2))
        .sum::<f64>()
        / n;
    (mean, var)
}

/// Runs `f(channel, chunk)` over the channels' chunks of `out` on two threads.
fn per_channel(out: &mut [f32], count: usize, f: impl Fn(usize, &mut [f32]) + Sync) {
    let channels = out.len() / count.max(1);
    let first_half = channels.div_ceil(2);
    let (first, second) = out.split_at_mut((first_half * count).min(out.len()));
    let f = &f;
    std::thread::scope(|scope| {
        scope.spawn(move || {
            for (c, chunk) in first.chunks_mut(count).enumerate() {
                f(c, chunk);
            }
        });
        for (c, chunk) in second.chunks_mut(count).enumerate() {
            f(first_half + c, chunk);
        }
    });
}

impl CustomOp3 for NormLeaky {
    fn name(&self) -> &'static str {
        "batch-norm-leaky-relu"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let (x, scale, shift) = (
            contiguous(s1, l1)?,
            contiguous(s2, l2)?,
            contiguous(s3, l3)?,
        );
        let channels = l1.dims()[0];
        if scale.len() != channels || shift.len() != channels || x.is_empty() {
            candle_core::bail!(
                "batch norm: {channels} channels, {} scales, {} shifts",
                scale.len(),
                shift.len()
            )
        }
        let count = x.len() / channels;
        let stats: Vec<(f64, f64)> = x.chunks(count).map(moments).collect();
        let mut out = vec![0f32; x.len()];
        per_channel(&mut out, count, |c, chunk| {
            let (mean, var) = stats[c];
            let a = scale[c] as f64 / (var + self.eps).sqrt();
            let (a, b) = (a as f32, (shift[c] as f64 - mean * a) as f32);
            for (y, &v) in chunk.iter_mut().zip(&x[c * count..(c + 1) * count]) {
                let z = a * v + b;
                *y = if z > 0.0 { z } else { self.slope * z };
            }
        });
        if let Ok(mut slot) = self.stats.lock() {
            *slot = Some(BatchStats {
                mean: stats.iter().map(|s| s.0).collect(),
                var: stats.iter().map(|s| s.1).collect(),
                count,
            });
        }
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }

    fn bwd(
        &self,
        arg1: &Tensor,
        arg2: &Tensor,
        _arg3: &Tensor,
        res: &Tensor,
        grad_res: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let x: Vec<f32> = arg1.flatten_all()?.to_vec1()?;
        let scale: Vec<f32> = arg2.to_vec1()?;
        let y: Vec<f32> = res.flatten_all()?.to_vec1()?;
        let g: Vec<f32> = grad_res.flatten_all()?.to_vec1()?;
        let channels = scale.len();
        let count = x.len() / channels.max(1);
        // The gradient before the activation: y > 0 exactly when its input was (the slope is
        // positive).
        let dz = |i: usize| if y[i] > 0.0 { g[i] } else { self.slope * g[i] } as f64;
        let mut d_scale = vec![0f32; channels];
        let mut d_shift = vec![0f32; channels];
        let mut sums = vec![(0f64, 0f64, 0f64, 0f64); channels];
        for (c, sum) in sums.iter_mut().enumerate() {
            let range = c * count..(c + 1) * count;
            let (mean, var) = moments(&x[range.clone()]);
            let inv_std = 1.0 / (var + self.eps).sqrt();
            let (mut sum_dz, mut sum_dz_xhat) = (0f64, 0f64);
            for i in range {
                sum_dz += dz(i);
                sum_dz_xhat += dz(i) * (x[i] as f64 - mean) * inv_std;
            }
            d_scale[c] = sum_dz_xhat as f32;
            d_shift[c] = sum_dz as f32;
            *sum = (mean, inv_std, sum_dz, sum_dz_xhat);
        }
        // dx = scale/σ · (dz − mean(dz) − x̂ · mean(dz · x̂)).
        let mut dx = vec![0f32; x.len()];
        per_channel(&mut dx, count, |c, chunk| {
            let (mean, inv_std, sum_dz, sum_dz_xhat) = sums[c];
            let n = count as f64;
            let factor = scale[c] as f64 * inv_std;
            for (k, d) in chunk.iter_mut().enumerate() {
                let i = c * count + k;
                let xhat = (x[i] as f64 - mean) * inv_std;
                *d = (factor * (dz(i) - sum_dz / n - xhat * sum_dz_xhat / n)) as f32;
            }
        });
        let device = arg1.device();
        Ok((
            Some(Tensor::from_vec(dx, arg1.shape(), device)?),
            Some(Tensor::from_vec(d_scale, channels, device)?),
            Some(Tensor::from_vec(d_shift, channels, device)?),
        ))
    }
}

/// Training-mode batch normalisation of `xs` [C, …] with `scale`, `shift` [C], then a leaky ReLU
/// of `slope`; also the batch's statistics.
pub fn batch_norm_leaky_relu(
    xs: &Tensor,
    scale: &Tensor,
    shift: &Tensor,
    eps: f64,
    slope: f64,
) -> candle_core::Result<(Tensor, BatchStats)> {
    let stats = Arc::new(Mutex::new(None));
    let op = NormLeaky {
        eps,
        slope: slope as f32,
        stats: Arc::clone(&stats),
    };
    let ys = xs.contiguous()?.apply_op3(scale, shift, op)?;
    let stats = stats.lock().ok().and_then(|mut s| s.take());
    let stats =
        stats.ok_or_else(|| candle_core::Error::Msg("batch norm left no statistics".into()))?;
    Ok((ys, stats))
}

#[cfg(test)]
mod tests {
    use super::*;
    use algorithms::vision::render::SplitMix64;
    use candle_core::{Device, Var};

    fn max_difference(a: &Tensor, b: &Tensor) -> f32 {
        (a - b)
            .unwrap()
            .abs()
            .unwrap()
            .max_all()
            .unwrap()
            .to_scalar()
            .unwrap()
    }

    /// The reference: the same arithmetic in candle's element-wise operations.
    fn composed(xs: &Tensor, scale: &Tensor, shift: &Tensor) -> Tensor {
        let (c, n) = (xs.dim(0).unwrap(), xs.elem_count() / xs.dim(0).unwrap());
        let flat = xs.reshape((c, n)).unwrap();
        let mean = flat.mean_keepdim(1).unwrap();
        let centred = flat.broadcast_sub(&mean).unwrap();
        let var = centred.sqr().unwrap().mean_keepdim(1).unwrap();
        let z = centred
            .broadcast_div(&(var + 1e-5).unwrap().sqrt().unwrap())
            .unwrap()
            .broadcast_mul(&scale.reshape((c, 1)).unwrap())
            .unwrap()
            .broadcast_add(&shift.reshape((c, 1)).unwrap())
            .unwrap();
        z.maximum(&(&z * 0.1).unwrap())
            .unwrap()
            .reshape(xs.dims())
            .unwrap()
    }

    #[test]
    fn values_gradients_and_statistics_match_the_composed_operations() {
        let device = Device::Cpu;
        let mut rng = SplitMix64::new(4);
        let mut random = |shape: &[usize], lo: f64, hi: f64| {
            let count: usize = shape.iter().product();
            let values: Vec<f32> = (0..count)
                .map(|_| (lo + (hi - lo) * rng.next_f64()) as f32)
                .collect();
            Tensor::from_vec(values, shape, &device).unwrap()
        };
        // Five channels (an odd count, split over the two threads) of values off zero.
        let xs = Var::from_tensor(&random(&[5, 3, 4, 6], -2.3, 3.7)).unwrap();
        let scale = Var::from_tensor(&random(&[5], 0.5, 1.5)).unwrap();
        let shift = Var::from_tensor(&random(&[5], -0.5, 0.5)).unwrap();
        let probe = random(&[5, 3, 4, 6], -1.0, 1.0);

        let (fused, stats) = batch_norm_leaky_relu(&xs, &scale, &shift, 1e-5, 0.1).unwrap();
        let reference = composed(&xs, &scale, &shift);
        assert!(max_difference(&fused, &reference) < 1e-5);
        let grads_fused = (&fused * &probe)
            .unwrap()
            .sum_all()
            .unwrap()
            .backward()
            .unwrap();
        let grads_ref = (&reference * &probe)
            .unwrap()
            .sum_all()
            .unwrap()
            .backward()
            .unwrap();
        for (name, var) in [("input", &xs), ("scale", &scale), ("shift", &shift)] {
            let difference =
                max_difference(grads_fused.get(var).unwrap(), grads_ref.get(var).unwrap());
            assert!(difference < 1e-4, "{name}: {difference}");
        }
        // The statistics of channel 2, by hand.
        let channel: Vec<f32> = xs.get(2).unwrap().flatten_all().unwrap().to_vec1().unwrap();
        let mean = channel.iter().map(|&v| v as f64).sum::<f64>() / 72.0;
        let var = channel
            .iter()
            .map(|&v| (v as f64 - mean).powi(2))
            .sum::<f64>()
            / 72.0;
        assert_eq!(stats.count, 72);
        assert!((stats.mean[2] - mean).abs() < 1e-9 && (stats.var[2] - var).abs() < 1e-9);
    }
}
