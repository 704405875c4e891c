//! The GPU backend (cargo feature `cuda`): ONNX Runtime with its CUDA execution provider, or on
//! the CPU (`backend = "onnxruntime-cpu"`, for a board without CUDA or to compare engines).
//!
//! `libonnxruntime.so` (a GPU build, e.g. the one JetPack's onnxruntime-gpu wheel installs) is
//! loaded at run time from `onnxruntime_library`, else `ORT_DYLIB_PATH`, else the loader's search
//! path, so building needs neither CUDA nor ONNX Runtime. If the library or the CUDA provider
//! cannot be had, opening fails with [`InferenceError::Unavailable`] and `auto` falls back to tract.

use super::{
    resolve_input, InferenceBackend, InferenceError, InputSpec, ModelSource, OutputTensor,
};
use ort::ep::{ExecutionProvider, CUDA};
use ort::session::Session;
use ort::value::{Tensor, ValueType};
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

/// Why ONNX Runtime could not be started; kept (shared) for every later task that asks.
#[derive(Debug, Clone, thiserror::Error)]
enum EnvironmentError {
    #[error("cannot load {}: {source}", path.display())]
    Load {
        path: PathBuf,
        #[source]
        source: Arc<ort::LoadDynamicError>,
    },
    #[error("cannot start ONNX Runtime: {0}")]
    Start(#[source] Arc<ort::Error>),
}

/// ONNX Runtime allows one environment per process; every hazard task (and restart) shares it.
static ENVIRONMENT: OnceLock<Result<ort::environment::Environment, EnvironmentError>> =
    OnceLock::new();

fn environment(
    library: Option<&Path>,
) -> Result<&'static ort::environment::Environment, EnvironmentError> {
    ENVIRONMENT
        .get_or_init(|| {
            let builder = match library {
                Some(path) => ort::init_from(path).map_err(|source| EnvironmentError::Load {
                    path: path.to_path_buf(),
                    source: Arc::new(source),
                })?,
                None => ort::init(),
            };
            builder
                .with_name("qosrt")
                .build()
                .map_err(|source| EnvironmentError::Start(Arc::new(source)))
        })
        .as_ref()
        .map_err(Clone::clone)
}

pub struct OrtBackend {
    name: &'static str,
    session: Session,
    input_name: String,
    input: InputSpec,
    model: String,
}

impl OrtBackend {
    pub fn open(
        source: &ModelSource,
        input_size_px: Option<(usize, usize)>,
        library: Option<&Path>,
        cuda: bool,
    ) -> Result<Self, InferenceError> {
        let unavailable = |why: String| InferenceError::Unavailable {
            backend: if cuda { "CUDA" } else { "ONNX Runtime" },
            why,
        };
        let model_name = source.to_string();
        let model_error = |message: String| InferenceError::Model {
            model: model_name.clone(),
            message,
        };
        let environment = environment(library).map_err(|e| unavailable(e.to_string()))?;
        let bytes = source.read()?;
        let mut builder = Session::builder(environment)
            .map_err(|e| unavailable(format!("cannot create a session: {e}")))?;
        if cuda {
            if !CUDA::is_available().unwrap_or(false) {
                return Err(unavailable(
                    "this ONNX Runtime has no CUDA execution provider (a CPU-only build?)".into(),
                ));
            }
            builder = builder
                .with_execution_providers([CUDA::default().build().error_on_failure()])
                .map_err(|e| unavailable(format!("the CUDA execution provider failed: {e}")))?;
        }
        let session = builder
            .commit_from_memory(&bytes)
            .map_err(|e| model_error(e.to_string()))?;
        let [input_outlet] = session.inputs() else {
            return Err(model_error(format!(
                "expected one image input, found {}",
                session.inputs().len()
            )));
        };
        let dims: Vec<Option<usize>> = match input_outlet.dtype() {
            ValueType::Tensor { shape, .. } => shape
                .iter()
                .map(|&d| usize::try_from(d).ok().filter(|_| d > 0))
                .collect(),
            other => return Err(model_error(format!("the input is not a tensor: {other}"))),
        };
        let input = resolve_input(&model_name, &dims, input_size_px)?;
        let input_name = input_outlet.name().to_string();
        Ok(Self {
            name: if cuda {
                "onnxruntime-cuda"
            } else {
                "onnxruntime-cpu"
            },
            session,
            input_name,
            input,
            model: model_name,
        })
    }
}

impl InferenceBackend for OrtBackend {
    fn name(&self) -> &'static str {
        self.name
    }

    fn input(&self) -> InputSpec {
        self.input
    }

    fn run(&mut self, input: &[f32]) -> Result<OutputTensor, InferenceError> {
        let run_error = |e: &dyn std::fmt::Display| InferenceError::Run {
            model: self.model.clone(),
            message: e.to_string(),
        };
        let shape = [
            1i64,
            self.input.channels as i64,
            self.input.height_px as i64,
            self.input.width_px as i64,
        ];
        let tensor = Tensor::from_array((shape, input.to_vec())).map_err(|e| run_error(&e))?;
        let outputs = self
            .session
            .run(ort::inputs![self.input_name.as_str() => tensor])
            .map_err(|e| run_error(&e))?;
        let (shape, values) = outputs[0]
            .try_extract_tensor::<f32>()
            .map_err(|e| run_error(&e))?;
        Ok(OutputTensor {
            shape: shape.iter().map(|&d| d.max(0) as usize).collect(),
            values: values.to_vec(),
        })
    }
}
