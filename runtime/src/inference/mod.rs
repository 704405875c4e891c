//! Running an ONNX model, behind one trait so the hazard task does not care which engine runs it:
//! - `tract` (pure Rust, CPU): always built, the default;
//! - ONNX Runtime with its CUDA execution provider: behind the `cuda` cargo feature, loading the
//!   board's `libonnxruntime.so` at run time (no build-time dependency on CUDA; see the README's
//!   "GPU build" section).
//!
//! Models are image models with one input `[1, C, H, W]` (C = 1 or 3) and one output.

pub mod pipeline;
mod tract_backend;

#[cfg(feature = "cuda")]
mod ort_backend;

use serde::Deserialize;
use std::fmt;
use std::path::{Path, PathBuf};

pub use tract_backend::TractBackend;

/// The model's input: one image, `channels × height × width`, batch 1.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InputSpec {
    pub channels: usize,
    pub height_px: usize,
    pub width_px: usize,
}

impl InputSpec {
    pub fn len(&self) -> usize {
        self.channels * self.height_px * self.width_px
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// One output tensor, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputTensor {
    pub shape: Vec<usize>,
    pub values: Vec<f32>,
}

/// A loaded model, ready to run.
pub trait InferenceBackend: Send {
    /// Short name for reports: `tract-cpu`, `onnxruntime-cuda`.
    fn name(&self) -> &'static str;
    fn input(&self) -> InputSpec;
    /// Runs one image, `input.len()` values laid out as [`InputSpec`] says.
    fn run(&mut self, input: &[f32]) -> Result<OutputTensor, InferenceError>;
}

/// Which engine `[task.params] backend` asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BackendChoice {
    /// CUDA when this binary has it and the board offers it, else the CPU (tract).
    #[default]
    Auto,
    /// tract on the CPU.
    Cpu,
    /// ONNX Runtime's CUDA execution provider (feature `cuda`).
    Cuda,
    /// ONNX Runtime on the CPU (feature `cuda`): the same library without a GPU.
    OnnxruntimeCpu,
}

/// Where the model comes from.
#[derive(Debug, Clone)]
pub enum ModelSource {
    File(PathBuf),
    /// A model compiled into the binary (the shipped hazard detector).
    Embedded {
        name: &'static str,
        bytes: &'static [u8],
    },
}

impl ModelSource {
    fn read(&self) -> Result<std::borrow::Cow<'static, [u8]>, InferenceError> {
        match self {
            ModelSource::File(path) => {
                std::fs::read(path)
                    .map(std::borrow::Cow::Owned)
                    .map_err(|source| InferenceError::Read {
                        path: path.clone(),
                        source,
                    })
            }
            ModelSource::Embedded { bytes, .. } => Ok(std::borrow::Cow::Borrowed(bytes)),
        }
    }
}

impl fmt::Display for ModelSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ModelSource::File(path) => write!(f, "{}", path.display()),
            ModelSource::Embedded { name, .. } => write!(f, "{name} (built in)"),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum InferenceError {
    #[error("cannot read the model file {}: {source}", path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{model}: not a usable ONNX model: {message}")]
    Model { model: String, message: String },
    #[error("{model}: input {shape}: {why}")]
    Input {
        model: String,
        shape: String,
        why: String,
    },
    #[error("{model}: inference failed: {message}")]
    Run { model: String, message: String },
    #[error("the {backend} backend is not available: {why}")]
    Unavailable { backend: &'static str, why: String },
}

/// Settings of [`open_backend`].
#[derive(Debug, Clone, Default)]
pub struct BackendOptions {
    pub choice: BackendChoice,
    /// Input height and width when the model leaves them open (a dynamic-shape export).
    pub input_size_px: Option<(usize, usize)>,
    /// Path of `libonnxruntime.so` for the CUDA backend (else `ORT_DYLIB_PATH`, else the loader's
    /// search path).
    pub onnxruntime_library: Option<PathBuf>,
}

/// A backend opened per `options`, and, when `auto` fell back to the CPU, why.
pub struct OpenedBackend {
    pub backend: Box<dyn InferenceBackend>,
    pub cpu_fallback_reason: Option<String>,
}

/// Loads the model on the chosen engine. `auto` tries CUDA first (when built in) and falls back
/// to tract, saying why; an explicit `cuda` that cannot be had is an error.
pub fn open_backend(
    source: &ModelSource,
    options: &BackendOptions,
) -> Result<OpenedBackend, InferenceError> {
    let cpu = |reason: Option<String>| -> Result<OpenedBackend, InferenceError> {
        Ok(OpenedBackend {
            backend: Box::new(TractBackend::open(source, options.input_size_px)?),
            cpu_fallback_reason: reason,
        })
    };
    match options.choice {
        BackendChoice::Cpu => cpu(None),
        BackendChoice::Cuda => Ok(OpenedBackend {
            backend: open_onnxruntime(source, options, true)?,
            cpu_fallback_reason: None,
        }),
        BackendChoice::OnnxruntimeCpu => Ok(OpenedBackend {
            backend: open_onnxruntime(source, options, false)?,
            cpu_fallback_reason: None,
        }),
        BackendChoice::Auto => match open_onnxruntime(source, options, true) {
            Ok(backend) => Ok(OpenedBackend {
                backend,
                cpu_fallback_reason: None,
            }),
            Err(InferenceError::Unavailable { why, .. }) => cpu(Some(why)),
            Err(other) => Err(other),
        },
    }
}

#[cfg(feature = "cuda")]
fn open_onnxruntime(
    source: &ModelSource,
    options: &BackendOptions,
    cuda: bool,
) -> Result<Box<dyn InferenceBackend>, InferenceError> {
    Ok(Box::new(ort_backend::OrtBackend::open(
        source,
        options.input_size_px,
        options.onnxruntime_library.as_deref(),
        cuda,
    )?))
}

#[cfg(not(feature = "cuda"))]
fn open_onnxruntime(
    _source: &ModelSource,
    _options: &BackendOptions,
    cuda: bool,
) -> Result<Box<dyn InferenceBackend>, InferenceError> {
    Err(InferenceError::Unavailable {
        backend: if cuda { "CUDA" } else { "ONNX Runtime" },
        why: "this binary was built without the `cuda` feature (cargo build --release --features cuda)"
            .to_string(),
    })
}

/// The input spec from a model's declared NCHW dims (`None` = left open), filled in from
/// `input_size_px` (height, width) where open. Shared by the backends so they agree.
pub(crate) fn resolve_input(
    model: &str,
    dims: &[Option<usize>],
    input_size_px: Option<(usize, usize)>,
) -> Result<InputSpec, InferenceError> {
    let shape = format!(
        "[{}]",
        dims.iter()
            .map(|d| d.map_or("?".to_string(), |d| d.to_string()))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let bad = |why: String| InferenceError::Input {
        model: model.to_string(),
        shape: shape.clone(),
        why,
    };
    let [batch, channels, height, width] = dims else {
        return Err(bad(format!(
            "expected an image input [1, C, H, W], got rank {}",
            dims.len()
        )));
    };
    if !matches!(batch, None | Some(1)) {
        return Err(bad("the batch must be 1 (or open)".into()));
    }
    let channels = channels.unwrap_or(3);
    if channels != 1 && channels != 3 {
        return Err(bad(format!(
            "expected 1 (grey) or 3 (RGB) channels, got {channels}"
        )));
    }
    let (height_px, width_px) = match (height, width, input_size_px) {
        (Some(h), Some(w), Some((h_param, w_param))) if (*h, *w) != (h_param, w_param) => {
            return Err(bad(format!(
                "the model is fixed at {h}×{w} (height × width) but the params ask for {h_param}×{w_param}"
            )))
        }
        (Some(h), Some(w), _) => (*h, *w),
        (h, w, Some((h_param, w_param))) => (h.unwrap_or(h_param), w.unwrap_or(w_param)),
        _ => {
            return Err(bad(
                "the model leaves its input size open: set input_height_px and input_width_px"
                    .into(),
            ))
        }
    };
    if height_px == 0 || width_px == 0 {
        return Err(bad("the input size must be positive".into()));
    }
    Ok(InputSpec {
        channels,
        height_px,
        width_px,
    })
}

/// `path` resolved against `dir` (the config's folder) when it is relative.
pub fn resolve_path(path: &Path, dir: Option<&Path>) -> PathBuf {
    match dir {
        Some(dir) if path.is_relative() => dir.join(path),
        _ => path.to_path_buf(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn input_dims_are_read_or_filled_from_the_params() {
        let fixed = resolve_input("m", &[Some(1), Some(1), Some(240), Some(320)], None).unwrap();
        assert_eq!(
            fixed,
            InputSpec {
                channels: 1,
                height_px: 240,
                width_px: 320
            }
        );
        // Open spatial dims (a dynamic export) take the params; an open channel count is RGB.
        let open = resolve_input("m", &[None, None, None, None], Some((416, 416))).unwrap();
        assert_eq!(
            (open.channels, open.height_px, open.width_px),
            (3, 416, 416)
        );
        let message = |dims: &[Option<usize>], size| {
            resolve_input("m.onnx", dims, size).unwrap_err().to_string()
        };
        assert!(message(&[None, None, None, None], None).contains("input_height_px"));
        assert!(message(&[Some(1), Some(1), Some(240)], None).contains("rank 3"));
        assert!(message(&[Some(2), Some(3), Some(8), Some(8)], None).contains("batch"));
        assert!(message(&[Some(1), Some(4), Some(8), Some(8)], None).contains("4"));
        let clash = message(&[Some(1), Some(1), Some(240), Some(320)], Some((320, 320)));
        assert!(
            clash.contains("240×320") && clash.contains("320×320"),
            "{clash}"
        );
    }

    #[test]
    fn relative_model_paths_resolve_against_the_config_folder() {
        let dir = Path::new("/missions/field");
        assert_eq!(
            resolve_path(Path::new("models/m.onnx"), Some(dir)),
            Path::new("/missions/field/models/m.onnx")
        );
        assert_eq!(
            resolve_path(Path::new("/abs/m.onnx"), Some(dir)),
            Path::new("/abs/m.onnx")
        );
        assert_eq!(resolve_path(Path::new("m.onnx"), None), Path::new("m.onnx"));
    }

    /// ONNX Runtime against tract on the shipped model: two engines, one answer. Needs a
    /// `libonnxruntime.so` (`ORT_DYLIB_PATH`; the onnxruntime wheel from PyPI has one) and the
    /// `cuda` feature; without the library it says so and passes.
    #[cfg(feature = "cuda")]
    #[test]
    fn onnxruntime_agrees_with_tract_and_a_cpu_only_library_has_no_cuda() {
        let Some(library) = std::env::var_os("ORT_DYLIB_PATH").map(PathBuf::from) else {
            eprintln!("skipped: set ORT_DYLIB_PATH to a libonnxruntime.so to run this test");
            return;
        };
        let source = crate::plugins::hazard_cnn::SHIPPED_MODEL;
        let options = |choice| BackendOptions {
            choice,
            input_size_px: None,
            onnxruntime_library: Some(library.clone()),
        };
        let mut tract = open_backend(&source, &options(BackendChoice::Cpu))
            .unwrap()
            .backend;
        let mut onnxruntime = open_backend(&source, &options(BackendChoice::OnnxruntimeCpu))
            .unwrap()
            .backend;
        assert_eq!(onnxruntime.name(), "onnxruntime-cpu");
        assert_eq!(onnxruntime.input(), tract.input());
        let mut state = 7u32;
        let input: Vec<f32> = (0..tract.input().len())
            .map(|_| {
                state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (state >> 8) as f32 / (1u32 << 24) as f32
            })
            .collect();
        let a = tract.run(&input).unwrap();
        let b = onnxruntime.run(&input).unwrap();
        assert_eq!(a.shape, b.shape);
        let worst = a
            .values
            .iter()
            .zip(&b.values)
            .map(|(x, y)| (x - y).abs() / (1.0 + x.abs()))
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-4, "engines differ by {worst}");
        // The PyPI build is CPU-only: `auto` falls back to tract and says why.
        let auto = open_backend(&source, &options(BackendChoice::Auto)).unwrap();
        if auto.backend.name() == "tract-cpu" {
            let reason = auto.cpu_fallback_reason.unwrap();
            assert!(reason.contains("CUDA"), "{reason}");
        }
    }
}
