//! The hazard detector: a small fully convolutional network with one YOLO head of stride 16, and
//! the decode of its raw output into `[cx, cy, w, h, objectness, p_person, p_animal, p_vehicle]`
//! rows — written once here in candle; the ONNX export writes the same arithmetic as graph nodes.

use crate::conv::ConvSpec;
use algorithms::vision::render::SplitMix64;
use candle_core::{DType, Device, Tensor, Var};
use thiserror::Error;

/// Network input, pixels: the 640×480 camera frame letterboxed at scale ½.
pub const INPUT_WIDTH_PX: usize = 320;
pub const INPUT_HEIGHT_PX: usize = 240;
/// Input pixels per output cell.
pub const STRIDE_PX: usize = 16;
/// person, animal, vehicle: the order of `sim::scene::HazardClass::ALL`.
pub const CLASSES: usize = 3;
/// Values per candidate: box (4), objectness, class probabilities.
pub const ATTRIBUTES: usize = 5 + CLASSES;
/// Slope of the leaky ReLU between layers.
pub const LEAKY_SLOPE: f64 = 0.1;
/// Batch normalisation: the variance floor and the weight of each batch in the running statistics.
pub const BATCH_NORM_EPS: f64 = 1e-5;
const BATCH_NORM_MOMENTUM: f64 = 0.1;
/// Prior objectness of the untrained head: almost every cell is background, and starting there
/// keeps the first steps from being spent unlearning a 50 % guess on 300 cells.
const OBJECTNESS_PRIOR: f64 = 0.01;

#[derive(Debug, Error)]
pub enum ModelError {
    #[error("layer {index}: {why}")]
    Layer { index: usize, why: String },
    #[error("the network needs at least one layer")]
    Empty,
    #[error("the layers' strides multiply to {found}, the head's stride must be {STRIDE_PX}")]
    Stride { found: usize },
    #[error("the anchor must be a positive, finite size in pixels, got {0}")]
    Anchor(f64),
    #[error("the input must be [batch, 1, height, width] with sides multiples of {STRIDE_PX}, got {0:?}")]
    InputShape(Vec<usize>),
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

/// The network's shape; the last layer is the head (no activation after it).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NetConfig {
    pub layers: Vec<ConvSpec>,
    /// The box size `exp(0)` stands for, input pixels.
    pub anchor_px: f64,
    /// Batch normalisation after every hidden convolution (folded into it on export): it lets
    /// Adam take large steps from the start, which the few minutes of training need.
    pub batch_norm: bool,
}

impl NetConfig {
    /// Four 3×3 stride-2 convolutions down to stride 16, then three stride-1 3×3 at dilations 1,
    /// 2 and 4 and the 1×1 head. The dilations widen the receptive field to 255 input pixels, so
    /// the cell at a vehicle's centre (150 px long at 7.5 m) sees both its ends.
    pub fn standard() -> Self {
        Self::with_widths([16, 32, 64, 64, 64, 64, 64])
    }

    /// The standard layout with other widths (tests use small ones).
    pub fn with_widths(widths: [usize; 7]) -> Self {
        let strides = [2, 2, 2, 2, 1, 1, 1];
        let dilations = [1, 1, 1, 1, 1, 2, 4];
        let mut layers = Vec::with_capacity(widths.len() + 1);
        let mut in_channels = 1;
        for ((out_channels, stride), dilation) in widths.into_iter().zip(strides).zip(dilations) {
            layers.push(ConvSpec {
                in_channels,
                out_channels,
                kernel: 3,
                stride,
                dilation,
            });
            in_channels = out_channels;
        }
        layers.push(ConvSpec {
            in_channels,
            out_channels: ATTRIBUTES,
            kernel: 1,
            stride: 1,
            dilation: 1,
        });
        Self {
            layers,
            anchor_px: 32.0,
            batch_norm: true,
        }
    }

    pub fn validate(&self) -> Result<(), ModelError> {
        let last = self.layers.last().ok_or(ModelError::Empty)?;
        let mut channels = 1;
        let mut stride = 1;
        for (index, layer) in self.layers.iter().enumerate() {
            let why = if layer.in_channels != channels {
                Some(format!(
                    "takes {} channels, the layer before gives {channels}",
                    layer.in_channels
                ))
            } else if layer.out_channels == 0 || layer.stride == 0 || layer.dilation == 0 {
                Some("channels, stride and dilation must be positive".to_string())
            } else if layer.kernel % 2 == 0 {
                Some(format!("kernel {} must be odd", layer.kernel))
            } else {
                None
            };
            if let Some(why) = why {
                return Err(ModelError::Layer { index, why });
            }
            channels = layer.out_channels;
            stride *= layer.stride;
        }
        if last.out_channels != ATTRIBUTES {
            return Err(ModelError::Layer {
                index: self.layers.len() - 1,
                why: format!(
                    "the head must give {ATTRIBUTES} channels, got {}",
                    last.out_channels
                ),
            });
        }
        if stride != STRIDE_PX {
            return Err(ModelError::Stride { found: stride });
        }
        if !(self.anchor_px.is_finite() && self.anchor_px > 0.0) {
            return Err(ModelError::Anchor(self.anchor_px));
        }
        Ok(())
    }
}

/// Whether batch normalisation uses the batch's statistics (and updates the running ones) or the
/// running ones, as the exported model does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    Train,
    Infer,
}

/// Batch normalisation of one layer's output channels.
#[derive(Debug, Clone)]
pub struct BatchNorm {
    /// [channels], trained.
    pub scale: Var,
    pub shift: Var,
    /// [channels], running averages over training batches (not trained by the optimiser).
    pub running_mean: Var,
    pub running_var: Var,
}

impl BatchNorm {
    /// Inference: `xs` [C, batch, H, W] normalised with the running statistics.
    fn infer(&self, xs: &Tensor) -> candle_core::Result<Tensor> {
        let (channels, batch, height, width) = xs.dims4()?;
        let flat = xs.reshape((channels, batch * height * width))?;
        let column = |v: &Var| v.as_tensor().reshape((channels, 1));
        let normed = flat
            .broadcast_sub(&column(&self.running_mean)?)?
            .broadcast_div(&(column(&self.running_var)? + BATCH_NORM_EPS)?.sqrt()?)?;
        normed
            .broadcast_mul(&column(&self.scale)?)?
            .broadcast_add(&column(&self.shift)?)?
            .reshape((channels, batch, height, width))
    }

    /// Training, with the leaky ReLU that always follows: the batch's statistics, which also
    /// move the running ones (unbiased variance: at inference the statistic is an estimate).
    fn train_then_activate(&self, xs: &Tensor) -> candle_core::Result<Tensor> {
        let (ys, stats) = crate::norm::batch_norm_leaky_relu(
            xs,
            self.scale.as_tensor(),
            self.shift.as_tensor(),
            BATCH_NORM_EPS,
            LEAKY_SLOPE,
        )?;
        let n = stats.count as f64;
        let unbiased: Vec<f64> = stats
            .var
            .iter()
            .map(|v| v * n / (n - 1.0).max(1.0))
            .collect();
        let m = BATCH_NORM_MOMENTUM;
        for (running, batch_value) in [
            (&self.running_mean, &stats.mean),
            (&self.running_var, &unbiased),
        ] {
            let old: Vec<f32> = running.to_vec1()?;
            let blended: Vec<f32> = old
                .iter()
                .zip(batch_value)
                .map(|(&r, &b)| ((1.0 - m) * r as f64 + m * b) as f32)
                .collect();
            running.set(&Tensor::from_vec(blended, old.len(), running.device())?)?;
        }
        Ok(ys)
    }
}

/// A convolution's numbers as the exported model holds them.
#[derive(Debug, Clone, PartialEq)]
pub struct ConvWeights {
    /// [out, in, kernel, kernel], row-major.
    pub weight: Vec<f32>,
    /// [out]
    pub bias: Vec<f32>,
}

/// One trainable convolution, with its batch normalisation if any.
#[derive(Debug, Clone)]
pub struct ConvLayer {
    pub spec: ConvSpec,
    /// [out, in, kernel, kernel]
    pub weight: Var,
    /// [out]
    pub bias: Var,
    pub norm: Option<BatchNorm>,
}

impl ConvLayer {
    /// `xs` and the result are channel-major, [C, batch, H, W] (see [`crate::conv`]); `activate`
    /// applies the leaky ReLU after the (normalised) convolution.
    fn forward(&self, xs: &Tensor, mode: Mode, activate: bool) -> candle_core::Result<Tensor> {
        let ys = crate::conv::conv2d_cbhw(
            xs,
            self.weight.as_tensor(),
            self.bias.as_tensor(),
            &self.spec,
        )?;
        match (&self.norm, mode, activate) {
            (Some(norm), Mode::Train, true) => norm.train_then_activate(&ys),
            (Some(_), Mode::Train, false) => {
                candle_core::bail!("batch normalisation is only trained before an activation")
            }
            (Some(norm), Mode::Infer, _) => {
                let ys = norm.infer(&ys)?;
                if activate {
                    leaky_relu(&ys)
                } else {
                    Ok(ys)
                }
            }
            (None, _, true) => leaky_relu(&ys),
            (None, _, false) => Ok(ys),
        }
    }

    /// The plain convolution the layer computes at inference: batch normalisation folded into
    /// the weights and bias, w′ = w·s/√(v + ε), b′ = (b − μ)·s/√(v + ε) + β per output channel.
    fn folded(&self) -> Result<ConvWeights, ModelError> {
        let weight: Vec<f32> = self.weight.flatten_all()?.to_vec1()?;
        let bias: Vec<f32> = self.bias.to_vec1()?;
        let Some(norm) = &self.norm else {
            return Ok(ConvWeights { weight, bias });
        };
        let values =
            |v: &Var| -> candle_core::Result<Vec<f64>> { v.to_dtype(DType::F64)?.to_vec1() };
        let (scale, shift) = (values(&norm.scale)?, values(&norm.shift)?);
        let (mean, var) = (values(&norm.running_mean)?, values(&norm.running_var)?);
        let per_channel = weight.len() / bias.len().max(1);
        let factor: Vec<f64> = scale
            .iter()
            .zip(&var)
            .map(|(s, v)| s / (v + BATCH_NORM_EPS).sqrt())
            .collect();
        let weight = weight
            .chunks(per_channel)
            .zip(&factor)
            .flat_map(|(w, f)| w.iter().map(move |x| (*x as f64 * f) as f32))
            .collect();
        let bias = (0..bias.len())
            .map(|o| ((bias[o] as f64 - mean[o]) * factor[o] + shift[o]) as f32)
            .collect();
        Ok(ConvWeights { weight, bias })
    }
}

/// The network and its weights.
#[derive(Debug, Clone)]
pub struct HazardNet {
    pub config: NetConfig,
    pub layers: Vec<ConvLayer>,
}

impl HazardNet {
    /// Fresh weights from `seed` (candle's own CPU generator cannot be seeded): He-normal for the
    /// hidden layers, a small head whose objectness starts at [`OBJECTNESS_PRIOR`].
    pub fn new(config: NetConfig, seed: u64, device: &Device) -> Result<Self, ModelError> {
        config.validate()?;
        let mut rng = SplitMix64::new(seed ^ 0x006e_6574);
        let head = config.layers.len() - 1;
        let mut layers = Vec::with_capacity(config.layers.len());
        for (index, &spec) in config.layers.iter().enumerate() {
            let fan_in = spec.in_channels * spec.kernel * spec.kernel;
            let std = if index == head {
                0.01
            } else {
                (2.0 / ((1.0 + LEAKY_SLOPE * LEAKY_SLOPE) * fan_in as f64)).sqrt()
            };
            let weights: Vec<f32> = (0..spec.out_channels * fan_in)
                .map(|_| (std * rng.next_gaussian()) as f32)
                .collect();
            let mut biases = vec![0f32; spec.out_channels];
            if index == head {
                biases[4] = (OBJECTNESS_PRIOR / (1.0 - OBJECTNESS_PRIOR)).ln() as f32;
            }
            let shape = (
                spec.out_channels,
                spec.in_channels,
                spec.kernel,
                spec.kernel,
            );
            let channels = spec.out_channels;
            let filled = |value: f32| -> candle_core::Result<Var> {
                Var::from_tensor(&Tensor::full(value, channels, device)?)
            };
            let norm = if config.batch_norm && index != head {
                Some(BatchNorm {
                    scale: filled(1.0)?,
                    shift: filled(0.0)?,
                    running_mean: filled(0.0)?,
                    running_var: filled(1.0)?,
                })
            } else {
                None
            };
            layers.push(ConvLayer {
                spec,
                weight: Var::from_tensor(&Tensor::from_vec(weights, shape, device)?)?,
                bias: Var::from_tensor(&Tensor::from_vec(biases, channels, device)?)?,
                norm,
            });
        }
        Ok(Self { config, layers })
    }

    /// Every trainable tensor, for the optimiser (not the running statistics).
    pub fn vars(&self) -> Vec<Var> {
        let mut vars = Vec::new();
        for l in &self.layers {
            vars.extend([l.weight.clone(), l.bias.clone()]);
            if let Some(n) = &l.norm {
                vars.extend([n.scale.clone(), n.shift.clone()]);
            }
        }
        vars
    }

    /// Trainable parameters in all.
    pub fn parameter_count(&self) -> usize {
        self.vars().iter().map(|v| v.elem_count()).sum()
    }

    /// The head's raw output, [batch, 8, height / 16, width / 16], for `images` [batch, 1,
    /// height, width] in [0, 1]. [`Mode::Train`] updates the running statistics.
    pub fn raw(&self, images: &Tensor, mode: Mode) -> Result<Tensor, ModelError> {
        let dims = images.dims().to_vec();
        let fits = dims.len() == 4
            && dims[1] == 1
            && dims[2] > 0
            && dims[3] > 0
            && dims[2].is_multiple_of(STRIDE_PX)
            && dims[3].is_multiple_of(STRIDE_PX);
        if !fits {
            return Err(ModelError::InputShape(dims));
        }
        // One channel: [batch, 1, H, W] and [1, batch, H, W] are the same numbers.
        let mut xs = images.reshape((1, dims[0], dims[2], dims[3]))?;
        let head = self.layers.len() - 1;
        for (index, layer) in self.layers.iter().enumerate() {
            xs = layer.forward(&xs, mode, index != head)?;
        }
        Ok(xs.transpose(0, 1)?.contiguous()?)
    }

    /// Raw output → [batch, cells, 8] rows as the ONNX model gives them: cells row-major over the
    /// grid, box in input pixels, objectness and classes through a sigmoid.
    pub fn decode(&self, raw: &Tensor) -> Result<Tensor, ModelError> {
        let (batch, _, rows, columns) = raw.dims4()?;
        let offsets = grid_offsets_px(rows, columns);
        let offsets = Tensor::from_vec(offsets, (1, 2, rows, columns), raw.device())?;
        let xy = (candle_nn::ops::sigmoid(&raw.narrow(1, 0, 2)?)? * (2.0 * STRIDE_PX as f64))?
            .broadcast_add(&offsets)?;
        let wh = (raw.narrow(1, 2, 2)?.exp()? * self.config.anchor_px)?;
        let scores = candle_nn::ops::sigmoid(&raw.narrow(1, 4, 1 + CLASSES)?)?;
        let rows_out = Tensor::cat(&[xy, wh, scores], 1)?
            .reshape((batch, ATTRIBUTES, rows * columns))?
            .transpose(1, 2)?
            .contiguous()?;
        Ok(rows_out)
    }

    /// [`Self::raw`] then [`Self::decode`].
    pub fn forward(&self, images: &Tensor, mode: Mode) -> Result<Tensor, ModelError> {
        self.decode(&self.raw(images, mode)?)
    }

    /// The inference weights as plain numbers, batch normalisation folded in, one entry per
    /// convolution, row-major.
    pub fn weights(&self) -> Result<Vec<ConvWeights>, ModelError> {
        self.layers.iter().map(ConvLayer::folded).collect()
    }
}

/// Leaky ReLU as max(x, slope·x): one comparison, and the same as ONNX's LeakyRelu.
pub fn leaky_relu(xs: &Tensor) -> candle_core::Result<Tensor> {
    xs.maximum(&(xs * LEAKY_SLOPE)?)
}

/// What the decode adds to `sigmoid(t) · 2 · stride` so the centre is
/// `(cell + 2 · sigmoid(t) − 0.5) · stride`: `(cell − 0.5) · stride`, as [2, rows, columns]
/// (x plane, then y plane), row-major.
pub fn grid_offsets_px(rows: usize, columns: usize) -> Vec<f32> {
    let stride = STRIDE_PX as f32;
    let x_plane = (0..rows).flat_map(|_| (0..columns).map(move |x| (x as f32 - 0.5) * stride));
    let y_plane = (0..rows).flat_map(|y| (0..columns).map(move |_| (y as f32 - 0.5) * stride));
    x_plane.chain(y_plane).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_decode_places_boxes_on_their_cells() {
        let device = Device::Cpu;
        let net = HazardNet::new(NetConfig::with_widths([2; 7]), 1, &device).unwrap();
        // A 2 × 3 grid of raw values: cell (row 1, column 2) has t = (0, 0, ln 2, 0, ...).
        let (rows, columns) = (2, 3);
        let mut raw = vec![0f32; ATTRIBUTES * rows * columns];
        let at = |channel: usize, y: usize, x: usize| (channel * rows + y) * columns + x;
        raw[at(0, 1, 2)] = 2.0;
        raw[at(2, 1, 2)] = 2f32.ln();
        raw[at(4, 1, 2)] = 3.0;
        let raw = Tensor::from_vec(raw, (1, ATTRIBUTES, rows, columns), &device).unwrap();
        let rows_out = net.decode(&raw).unwrap();
        assert_eq!(rows_out.dims(), &[1, 6, ATTRIBUTES]);
        let values: Vec<Vec<f32>> = rows_out.squeeze(0).unwrap().to_vec2().unwrap();
        let sigmoid = |t: f64| 1.0 / (1.0 + (-t).exp());
        // Candidate 5 is row 1, column 2.
        let expected = [
            (2.0 + 2.0 * sigmoid(2.0) - 0.5) * 16.0,
            (1.0 + 2.0 * 0.5 - 0.5) * 16.0,
            64.0,
            32.0,
            sigmoid(3.0),
            0.5,
            0.5,
            0.5,
        ];
        for (got, want) in values[5].iter().zip(expected) {
            assert!((*got as f64 - want).abs() < 1e-4, "{:?}", values[5]);
        }
        // Candidate 0 sits on cell (0, 0): centre at half a stride.
        assert!((values[0][0] - 8.0).abs() < 1e-5 && (values[0][1] - 8.0).abs() < 1e-5);
    }

    #[test]
    fn bad_configs_are_named_errors() {
        let mut config = NetConfig::standard();
        config.layers[1].in_channels = 7;
        assert!(matches!(
            config.validate(),
            Err(ModelError::Layer { index: 1, .. })
        ));
        let mut config = NetConfig::standard();
        config.layers[4].stride = 2;
        assert!(matches!(
            config.validate(),
            Err(ModelError::Stride { found: 32 })
        ));
        let mut config = NetConfig::standard();
        config.anchor_px = 0.0;
        assert!(matches!(config.validate(), Err(ModelError::Anchor(_))));
        let net = HazardNet::new(NetConfig::standard(), 0, &Device::Cpu).unwrap();
        let odd = Tensor::zeros((1, 1, 40, 30), DType::F32, &Device::Cpu).unwrap();
        assert!(matches!(
            net.raw(&odd, Mode::Infer),
            Err(ModelError::InputShape(_))
        ));
    }
}
