//! Convolution for training as im2col + matrix product. candle's own CPU convolution computes
//! its gradients with a direct (non-GEMM) transposed convolution, six times slower than its
//! forward pass on this network; here the gradient of the patch gathering is its exact adjoint
//! (scatter-add) and everything else is a matrix product, whose gradients are matrix products.
//! The arithmetic is the ONNX `Conv`'s: the export writes plain Conv nodes.
//!
//! Tensors here are channel-major, [C, batch, H, W]: then one matrix product covers the whole
//! batch, [C_out, C·k·k] × [C·k·k, batch·H_out·W_out], and its result is already the next
//! layer's [C_out, batch, H_out, W_out] input, with no transposes in between. For a batch of one
//! the layout is ONNX's NCHW.

use candle_core::{CpuStorage, CustomOp1, Layout, Shape, Tensor};

/// One convolution: `kernel × kernel` taps `dilation` apart, zero padding that keeps the size
/// (`dilation · (kernel / 2)`) before the stride.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ConvSpec {
    pub in_channels: usize,
    pub out_channels: usize,
    pub kernel: usize,
    pub stride: usize,
    pub dilation: usize,
}

impl ConvSpec {
    pub fn padding(&self) -> usize {
        self.dilation * (self.kernel / 2)
    }
}

/// Geometry of one convolution over a [channels, batch, height, width] input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Geometry {
    batch: usize,
    channels: usize,
    height: usize,
    width: usize,
    kernel: usize,
    stride: usize,
    dilation: usize,
    padding: usize,
    out_height: usize,
    out_width: usize,
}

impl Geometry {
    fn new(dims: &[usize], spec: &ConvSpec) -> candle_core::Result<Self> {
        let &[channels, batch, height, width] = dims else {
            candle_core::bail!(
                "im2col needs a [channels, batch, height, width] input, got {dims:?}"
            )
        };
        let (k, s, d, p) = (spec.kernel, spec.stride, spec.dilation, spec.padding());
        let reach = d * (k - 1) + 1;
        if height + 2 * p < reach || width + 2 * p < reach || s == 0 {
            candle_core::bail!("a {height}×{width} input is smaller than the {reach}-pixel kernel")
        }
        Ok(Self {
            batch,
            channels,
            height,
            width,
            kernel: k,
            stride: s,
            dilation: d,
            padding: p,
            out_height: (height + 2 * p - reach) / s + 1,
            out_width: (width + 2 * p - reach) / s + 1,
        })
    }

    fn patch_len(&self) -> usize {
        self.channels * self.kernel * self.kernel
    }

    fn cells(&self) -> usize {
        self.out_height * self.out_width
    }

    /// For kernel offset `k` along an axis of `size`, the output positions whose tap lands inside
    /// the input, and the input index of the first: taps are `o · stride + k · dilation − padding`.
    fn valid(&self, k: usize, size: usize, out_size: usize) -> (usize, usize, isize) {
        let offset = (k * self.dilation) as isize - self.padding as isize;
        let s = self.stride as isize;
        // First o with o·s + offset ≥ 0, last with o·s + offset ≤ size − 1.
        let first = if offset >= 0 {
            0
        } else {
            ((-offset) + s - 1) / s
        };
        let last = (size as isize - 1 - offset).div_euclid(s);
        let end = (last + 1).clamp(0, out_size as isize);
        let first = first.min(end);
        (first as usize, end as usize, offset)
    }

    /// Calls `f(column index, input index)` for every in-bounds tap of one (channel, ky, kx) row,
    /// with both indices relative to their planes.
    fn for_each_tap(&self, ky: usize, kx: usize, mut f: impl FnMut(usize, usize)) {
        let (y0, y1, oy_off) = self.valid(ky, self.height, self.out_height);
        let (x0, x1, ox_off) = self.valid(kx, self.width, self.out_width);
        for oy in y0..y1 {
            let iy = (oy as isize * self.stride as isize + oy_off) as usize;
            for ox in x0..x1 {
                let ix = (ox as isize * self.stride as isize + ox_off) as usize;
                f(oy * self.out_width + ox, iy * self.width + ix);
            }
        }
    }
}

/// [C, batch, H, W] → [C·k·k, batch·H_out·W_out]: row (c·k + ky)·k + kx holds input channel c
/// at kernel offset (ky, kx) for every image and output cell, zero where the tap falls in the
/// padding.
struct Im2Col(ConvSpec);

/// The adjoint of [`Im2Col`]: each column value added back to the input pixel it came from.
struct Col2Im {
    geometry: Geometry,
}

fn contiguous<'a>(storage: &'a CpuStorage, layout: &Layout) -> candle_core::Result<&'a [f32]> {
    let Some((start, end)) = layout.contiguous_offsets() else {
        candle_core::bail!("im2col needs a contiguous input")
    };
    Ok(&storage.as_slice::<f32>()?[start..end])
}

impl CustomOp1 for Im2Col {
    fn name(&self) -> &'static str {
        "im2col"
    }

    fn cpu_fwd(
        &self,
        storage: &CpuStorage,
        layout: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let g = Geometry::new(layout.dims(), &self.0)?;
        let input = contiguous(storage, layout)?;
        let (plane, cells, k) = (g.height * g.width, g.cells(), g.kernel);
        let row_len = g.batch * cells;
        let mut out = vec![0f32; g.patch_len() * row_len];
        for c in 0..g.channels {
            for b in 0..g.batch {
                let source = &input[(c * g.batch + b) * plane..][..plane];
                for ky in 0..k {
                    for kx in 0..k {
                        let row = (c * k + ky) * k + kx;
                        let target = &mut out[row * row_len + b * cells..][..cells];
                        g.for_each_tap(ky, kx, |column, pixel| target[column] = source[pixel]);
                    }
                }
            }
        }
        let shape = Shape::from((g.patch_len(), row_len));
        Ok((CpuStorage::F32(out), shape))
    }

    fn bwd(
        &self,
        arg: &Tensor,
        _res: &Tensor,
        grad_res: &Tensor,
    ) -> candle_core::Result<Option<Tensor>> {
        let geometry = Geometry::new(arg.dims(), &self.0)?;
        let grad = grad_res
            .contiguous()?
            .apply_op1_no_bwd(&Col2Im { geometry })?;
        Ok(Some(grad))
    }
}

impl CustomOp1 for Col2Im {
    fn name(&self) -> &'static str {
        "col2im"
    }

    fn cpu_fwd(
        &self,
        storage: &CpuStorage,
        layout: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let g = self.geometry;
        let columns = contiguous(storage, layout)?;
        let (plane, cells, k) = (g.height * g.width, g.cells(), g.kernel);
        let row_len = g.batch * cells;
        if columns.len() != g.patch_len() * row_len {
            candle_core::bail!("col2im got {} values for {g:?}", columns.len())
        }
        let mut out = vec![0f32; g.channels * g.batch * plane];
        for c in 0..g.channels {
            for b in 0..g.batch {
                let target = &mut out[(c * g.batch + b) * plane..][..plane];
                for ky in 0..k {
                    for kx in 0..k {
                        let row = (c * k + ky) * k + kx;
                        let source = &columns[row * row_len + b * cells..][..cells];
                        g.for_each_tap(ky, kx, |column, pixel| target[pixel] += source[column]);
                    }
                }
            }
        }
        let shape = Shape::from((g.channels, g.batch, g.height, g.width));
        Ok((CpuStorage::F32(out), shape))
    }
}

/// `xs` [C, batch, H, W] convolved with `weight` [C_out, C, k, k] plus `bias` [C_out], as ONNX
/// `Conv` with `spec`'s stride, dilation and padding: [C_out, batch, H_out, W_out].
pub fn conv2d_cbhw(
    xs: &Tensor,
    weight: &Tensor,
    bias: &Tensor,
    spec: &ConvSpec,
) -> candle_core::Result<Tensor> {
    let g = Geometry::new(xs.dims(), spec)?;
    let columns = xs.contiguous()?.apply_op1(Im2Col(*spec))?;
    let kernel = weight.reshape((spec.out_channels, g.patch_len()))?;
    let ys = kernel.matmul(&columns)?;
    let ys = ys.reshape((spec.out_channels, g.batch, g.out_height, g.out_width))?;
    ys.broadcast_add(&bias.reshape((spec.out_channels, 1, 1, 1))?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use algorithms::vision::render::SplitMix64;
    use candle_core::{Device, Var};

    fn random(shape: &[usize], rng: &mut SplitMix64) -> Tensor {
        let count: usize = shape.iter().product();
        let values: Vec<f32> = (0..count).map(|_| rng.next_gaussian() as f32).collect();
        Tensor::from_vec(values, shape, &Device::Cpu).unwrap()
    }

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

    /// The value and gradients of candle's own convolution are the reference.
    #[test]
    fn values_and_gradients_match_candles_convolution() {
        let mut rng = SplitMix64::new(7);
        for (kernel, stride, dilation, height, width) in [
            (3, 2, 1, 16, 12),
            (3, 1, 1, 6, 5),
            (3, 1, 2, 8, 8),
            (3, 1, 4, 10, 9),
            (1, 1, 1, 4, 6),
            (3, 2, 1, 7, 9),
        ] {
            let spec = ConvSpec {
                in_channels: 3,
                out_channels: 4,
                kernel,
                stride,
                dilation,
            };
            let xs = Var::from_tensor(&random(&[2, 3, height, width], &mut rng)).unwrap();
            let xs_cbhw = xs.transpose(0, 1).unwrap();
            let weight = Var::from_tensor(&random(&[4, 3, kernel, kernel], &mut rng)).unwrap();
            let bias = Var::from_tensor(&random(&[4], &mut rng)).unwrap();
            // A loss that weighs every output differently, so each gradient entry is distinct.
            let mine = conv2d_cbhw(&xs_cbhw, &weight, &bias, &spec)
                .unwrap()
                .transpose(0, 1)
                .unwrap();
            let probe = random(mine.dims(), &mut rng);
            let reference = xs
                .conv2d(&weight, spec.padding(), stride, dilation, 1)
                .unwrap()
                .broadcast_add(&bias.reshape((1, 4, 1, 1)).unwrap())
                .unwrap();
            assert_eq!(mine.dims(), reference.dims());
            let case = format!("k{kernel} s{stride} d{dilation} {height}×{width}");
            assert!(max_difference(&mine, &reference) < 1e-4, "{case}: values");
            let grads_mine = (&mine * &probe)
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
            for (name, var) in [("input", &xs), ("weight", &weight), ("bias", &bias)] {
                let a = grads_mine.get(var).unwrap();
                let b = grads_ref.get(var).unwrap();
                assert!(max_difference(a, b) < 1e-3, "{case}: {name} gradient");
            }
        }
    }
}
