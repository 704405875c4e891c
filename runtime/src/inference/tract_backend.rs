//! The CPU backend: tract, pure Rust, nothing to install.

use super::{
    resolve_input, InferenceBackend, InferenceError, InputSpec, ModelSource, OutputTensor,
};
use std::sync::Arc;
use tract_onnx::prelude::*;
use tract_onnx::tract_hir::infer::Factoid;

pub struct TractBackend {
    plan: Arc<TypedRunnableModel>,
    input: InputSpec,
    model: String,
}

impl TractBackend {
    /// Loads and optimises the model for a fixed `[1, C, H, W]` input. Anything wrong with the
    /// file (not ONNX, an operator tract lacks, an input that is not an image) is an error here,
    /// at start-up, not at the first frame.
    pub fn open(
        source: &ModelSource,
        input_size_px: Option<(usize, usize)>,
    ) -> Result<Self, InferenceError> {
        let model_name = source.to_string();
        let bytes = source.read()?;
        let model_error = |e: TractError| InferenceError::Model {
            model: model_name.clone(),
            message: format!("{e:#}"),
        };
        let mut model = tract_onnx::onnx()
            .model_for_read(&mut &bytes[..])
            .map_err(model_error)?;
        if model.inputs.len() != 1 || model.outputs.is_empty() {
            return Err(InferenceError::Model {
                model: model_name,
                message: format!(
                    "expected one image input and an output, found {} inputs and {} outputs",
                    model.inputs.len(),
                    model.outputs.len()
                ),
            });
        }
        let fact = model.input_fact(0).map_err(model_error)?;
        let dims: Vec<Option<usize>> = fact
            .shape
            .dims()
            .map(|d| {
                d.concretize()
                    .and_then(|d| d.as_i64())
                    .and_then(|d| usize::try_from(d).ok())
            })
            .collect();
        let input = resolve_input(&model_name, &dims, input_size_px)?;
        model
            .set_input_fact(
                0,
                f32::fact([1, input.channels, input.height_px, input.width_px]).into(),
            )
            .map_err(model_error)?;
        // Only the first output is read: YOLO exports put the detections there.
        let first_output = model.outputs[0];
        model
            .select_output_outlets(&[first_output])
            .map_err(model_error)?;
        let plan = model
            .into_optimized()
            .and_then(|m| m.into_runnable())
            .map_err(model_error)?;
        Ok(Self {
            plan,
            input,
            model: model_name,
        })
    }
}

impl InferenceBackend for TractBackend {
    fn name(&self) -> &'static str {
        "tract-cpu"
    }

    fn input(&self) -> InputSpec {
        self.input
    }

    fn run(&mut self, input: &[f32]) -> Result<OutputTensor, InferenceError> {
        let run_error = |e: TractError| InferenceError::Run {
            model: self.model.clone(),
            message: format!("{e:#}"),
        };
        let shape = [
            1,
            self.input.channels,
            self.input.height_px,
            self.input.width_px,
        ];
        let tensor = Tensor::from_shape(&shape, input).map_err(run_error)?;
        let outputs = self.plan.run(tvec!(tensor.into())).map_err(run_error)?;
        let output = outputs[0].to_plain_array_view::<f32>().map_err(run_error)?;
        Ok(OutputTensor {
            shape: output.shape().to_vec(),
            values: output.iter().copied().collect(),
        })
    }
}
