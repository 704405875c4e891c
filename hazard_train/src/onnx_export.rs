//! Writes the trained network as an ONNX model (opset 13) the hazard task loads: input `images`
//! [1, 1, height, width], output `detections` [1, cells, 8] with the YOLO decode inside the graph
//! — the arithmetic of [`HazardNet::decode`] as Split, Sigmoid, Exp, Mul, Add, Concat, Reshape and
//! Transpose nodes — so `algorithms::vision::yolo::decode` reads the output as it is.

use std::path::Path;

use prost::Message;
use thiserror::Error;
use tract_onnx::pb::{
    attribute_proto::AttributeType, tensor_proto::DataType, tensor_shape_proto, type_proto,
    AttributeProto, GraphProto, ModelProto, NodeProto, OperatorSetIdProto, StringStringEntryProto,
    TensorProto, TensorShapeProto, TypeProto, ValueInfoProto,
};

use crate::model::{
    grid_offsets_px, ConvWeights, HazardNet, ModelError, ATTRIBUTES, CLASSES, LEAKY_SLOPE,
    STRIDE_PX,
};

/// The graph's input and output names: the hazard task's contract.
pub const INPUT_NAME: &str = "images";
pub const OUTPUT_NAME: &str = "detections";
pub const OPSET: i64 = 13;
/// ONNX IR version 7 goes with opset 13.
const IR_VERSION: i64 = 7;

#[derive(Debug, Error)]
pub enum ExportError {
    #[error(
        "the input {width_px}×{height_px} must be a positive multiple of {STRIDE_PX} px a side"
    )]
    InputSize { width_px: usize, height_px: usize },
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error("writing {path}: {source}")]
    Write {
        path: String,
        source: std::io::Error,
    },
}

/// Facts stored with the model (ONNX metadata), for people and tools that open it.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportInfo<'a> {
    pub class_names: &'a [&'a str],
    pub description: &'a str,
}

/// The ONNX model of `net` for a fixed input size.
pub fn export(
    net: &HazardNet,
    input_width_px: usize,
    input_height_px: usize,
    info: &ExportInfo<'_>,
) -> Result<ModelProto, ExportError> {
    check_input_size(input_width_px, input_height_px)?;
    net.config.validate()?;
    let (rows, columns) = (input_height_px / STRIDE_PX, input_width_px / STRIDE_PX);
    let cells = rows * columns;
    let mut nodes = Vec::new();
    let mut initializers = Vec::new();

    let current = push_conv_layers(net, &mut nodes, &mut initializers)?;
    push_decode(net, &current, rows, columns, &mut nodes, &mut initializers);

    let graph = GraphProto {
        node: nodes,
        name: "hazard_yolo".into(),
        initializer: initializers,
        input: vec![value_info(
            INPUT_NAME,
            &[1, 1, input_height_px, input_width_px],
        )],
        output: vec![value_info(OUTPUT_NAME, &[1, cells, ATTRIBUTES])],
        ..Default::default()
    };
    Ok(model_proto(
        net,
        graph,
        input_width_px,
        input_height_px,
        info,
    ))
}

/// The input must tile into whole grid cells.
fn check_input_size(input_width_px: usize, input_height_px: usize) -> Result<(), ExportError> {
    let fits = |side: usize| side > 0 && side.is_multiple_of(STRIDE_PX);
    if !(fits(input_width_px) && fits(input_height_px)) {
        return Err(ExportError::InputSize {
            width_px: input_width_px,
            height_px: input_height_px,
        });
    }
    Ok(())
}

/// The convolution stack from the input to the head's raw output: a Conv per layer (batch
/// normalisation folded into its weights) and a LeakyRelu after every layer but the head.
/// Returns the name of the head's output.
fn push_conv_layers(
    net: &HazardNet,
    nodes: &mut Vec<NodeProto>,
    initializers: &mut Vec<TensorProto>,
) -> Result<String, ExportError> {
    let mut current = INPUT_NAME.to_string();
    let head = net.layers.len() - 1;
    for (index, (ConvWeights { weight, bias }, layer)) in
        net.weights()?.into_iter().zip(&net.layers).enumerate()
    {
        let s = layer.spec;
        let (w_name, b_name) = (format!("conv{index}.weight"), format!("conv{index}.bias"));
        initializers.push(float_tensor(
            &w_name,
            &[s.out_channels, s.in_channels, s.kernel, s.kernel],
            weight,
        ));
        initializers.push(float_tensor(&b_name, &[s.out_channels], bias));
        let conv_out = if index == head {
            "raw".to_string()
        } else {
            format!("conv{index}")
        };
        let (k, st, p, d) = (
            s.kernel as i64,
            s.stride as i64,
            s.padding() as i64,
            s.dilation as i64,
        );
        nodes.push(node(
            "Conv",
            &[&current, &w_name, &b_name],
            &[&conv_out],
            vec![
                ints("kernel_shape", &[k, k]),
                ints("strides", &[st, st]),
                ints("pads", &[p, p, p, p]),
                ints("dilations", &[d, d]),
                int("group", 1),
            ],
        ));
        current = conv_out;
        if index != head {
            let act = format!("act{index}");
            nodes.push(node(
                "LeakyRelu",
                &[&current],
                &[&act],
                vec![float("alpha", LEAKY_SLOPE as f32)],
            ));
            current = act;
        }
    }
    Ok(current)
}

/// The decode, channel groups as in HazardNet::decode: from the head's raw output `current`
/// to the `detections` output, [1, cells, ATTRIBUTES].
fn push_decode(
    net: &HazardNet,
    current: &str,
    rows: usize,
    columns: usize,
    nodes: &mut Vec<NodeProto>,
    initializers: &mut Vec<TensorProto>,
) {
    let cells = rows * columns;
    initializers.push(int64_tensor("split_sizes", &[2, 2, 1 + CLASSES as i64]));
    initializers.push(float_tensor("xy_scale", &[], vec![2.0 * STRIDE_PX as f32]));
    initializers.push(float_tensor(
        "grid_offsets_px",
        &[1, 2, rows, columns],
        grid_offsets_px(rows, columns),
    ));
    initializers.push(float_tensor(
        "anchor_px",
        &[],
        vec![net.config.anchor_px as f32],
    ));
    initializers.push(int64_tensor(
        "rows_shape",
        &[1, ATTRIBUTES as i64, cells as i64],
    ));
    nodes.push(node(
        "Split",
        &[current, "split_sizes"],
        &["raw_xy", "raw_wh", "raw_scores"],
        vec![int("axis", 1)],
    ));
    nodes.push(node("Sigmoid", &["raw_xy"], &["xy_unit"], vec![]));
    nodes.push(node("Mul", &["xy_unit", "xy_scale"], &["xy_shift"], vec![]));
    nodes.push(node(
        "Add",
        &["xy_shift", "grid_offsets_px"],
        &["xy"],
        vec![],
    ));
    nodes.push(node("Exp", &["raw_wh"], &["wh_unit"], vec![]));
    nodes.push(node("Mul", &["wh_unit", "anchor_px"], &["wh"], vec![]));
    nodes.push(node("Sigmoid", &["raw_scores"], &["scores"], vec![]));
    nodes.push(node(
        "Concat",
        &["xy", "wh", "scores"],
        &["decoded_grid"],
        vec![int("axis", 1)],
    ));
    nodes.push(node(
        "Reshape",
        &["decoded_grid", "rows_shape"],
        &["decoded_rows"],
        vec![],
    ));
    nodes.push(node(
        "Transpose",
        &["decoded_rows"],
        &[OUTPUT_NAME],
        vec![ints("perm", &[0, 2, 1])],
    ));
}

/// The model around `graph`: opset, producer and the metadata for people and tools.
fn model_proto(
    net: &HazardNet,
    graph: GraphProto,
    input_width_px: usize,
    input_height_px: usize,
    info: &ExportInfo<'_>,
) -> ModelProto {
    let metadata = [
        ("class_names", info.class_names.join(",")),
        ("input_width_px", input_width_px.to_string()),
        ("input_height_px", input_height_px.to_string()),
        ("stride_px", STRIDE_PX.to_string()),
        ("anchor_px", net.config.anchor_px.to_string()),
        (
            "output_layout",
            "[cx, cy, w, h, objectness, class probabilities...] in input pixels".into(),
        ),
    ];
    ModelProto {
        ir_version: IR_VERSION,
        opset_import: vec![OperatorSetIdProto {
            domain: String::new(),
            version: OPSET,
        }],
        producer_name: "qosrt hazard_train".into(),
        producer_version: env!("CARGO_PKG_VERSION").into(),
        doc_string: info.description.into(),
        graph: Some(graph),
        metadata_props: metadata
            .into_iter()
            .map(|(key, value)| StringStringEntryProto {
                key: key.into(),
                value,
            })
            .collect(),
        ..Default::default()
    }
}

/// Serialises `model` to `path`.
pub fn write(model: &ModelProto, path: &Path) -> Result<usize, ExportError> {
    let bytes = model.encode_to_vec();
    std::fs::write(path, &bytes).map_err(|source| ExportError::Write {
        path: path.display().to_string(),
        source,
    })?;
    Ok(bytes.len())
}

fn node(
    op_type: &str,
    inputs: &[&str],
    outputs: &[&str],
    attribute: Vec<AttributeProto>,
) -> NodeProto {
    NodeProto {
        input: inputs.iter().map(|s| s.to_string()).collect(),
        output: outputs.iter().map(|s| s.to_string()).collect(),
        name: format!("{op_type}:{}", outputs[0]),
        op_type: op_type.into(),
        attribute,
        ..Default::default()
    }
}

fn ints(name: &str, values: &[i64]) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: AttributeType::Ints as i32,
        ints: values.to_vec(),
        ..Default::default()
    }
}

fn int(name: &str, value: i64) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: AttributeType::Int as i32,
        i: value,
        ..Default::default()
    }
}

fn float(name: &str, value: f32) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: AttributeType::Float as i32,
        f: value,
        ..Default::default()
    }
}

fn float_tensor(name: &str, dims: &[usize], values: Vec<f32>) -> TensorProto {
    TensorProto {
        name: name.into(),
        dims: dims.iter().map(|&d| d as i64).collect(),
        data_type: DataType::Float as i32,
        // Little-endian raw bytes: the compact form every runtime reads.
        raw_data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        ..Default::default()
    }
}

fn int64_tensor(name: &str, values: &[i64]) -> TensorProto {
    TensorProto {
        name: name.into(),
        dims: vec![values.len() as i64],
        data_type: DataType::Int64 as i32,
        raw_data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        ..Default::default()
    }
}

fn value_info(name: &str, dims: &[usize]) -> ValueInfoProto {
    ValueInfoProto {
        name: name.into(),
        r#type: Some(TypeProto {
            value: Some(type_proto::Value::TensorType(type_proto::Tensor {
                elem_type: DataType::Float as i32,
                shape: Some(TensorShapeProto {
                    dim: dims
                        .iter()
                        .map(|&d| tensor_shape_proto::Dimension {
                            value: Some(tensor_shape_proto::dimension::Value::DimValue(d as i64)),
                            ..Default::default()
                        })
                        .collect(),
                }),
            })),
            ..Default::default()
        }),
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluate::OnnxDetector;
    use crate::model::{Mode, NetConfig};
    use algorithms::vision::render::SplitMix64;
    use candle_core::{Device, Tensor};

    #[test]
    fn the_exported_graph_computes_what_the_candle_network_computes() {
        let device = Device::Cpu;
        // Narrow layers keep the test fast; the graph's structure is the shipped one.
        let mut net =
            HazardNet::new(NetConfig::with_widths([4, 6, 8, 8, 8, 8, 8]), 42, &device).unwrap();
        // A fresh head outputs near-constant values; spread them so the decode is exercised.
        let head = net.layers.last_mut().unwrap();
        let spread = (head.weight.as_tensor() * 40.0).unwrap();
        head.weight.set(&spread).unwrap();
        // And start the objectness at 50 %, where the sigmoid is steep.
        head.bias.set(&head.bias.zeros_like().unwrap()).unwrap();
        // Batch normalisation as after training: scales, shifts and running statistics far from
        // their initial 1 and 0, so the folding into the exported convolutions is exercised.
        let mut rng = SplitMix64::new(9);
        for layer in &net.layers {
            let Some(norm) = &layer.norm else { continue };
            let channels = layer.spec.out_channels;
            let mut random = |lo: f64, hi: f64| {
                let values: Vec<f32> = (0..channels)
                    .map(|_| (lo + (hi - lo) * rng.next_f64()) as f32)
                    .collect();
                Tensor::from_vec(values, channels, &device).unwrap()
            };
            norm.scale.set(&random(0.5, 1.5)).unwrap();
            norm.shift.set(&random(-0.5, 0.5)).unwrap();
            norm.running_mean.set(&random(-0.3, 0.3)).unwrap();
            norm.running_var.set(&random(0.3, 2.0)).unwrap();
        }
        let (width, height) = (320, 240);
        let input: Vec<f32> = (0..width * height).map(|_| rng.next_f64() as f32).collect();
        let images = Tensor::from_vec(input.clone(), (1, 1, height, width), &device).unwrap();
        let expected: Vec<f32> = net
            .forward(&images, Mode::Infer)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1()
            .unwrap();

        let info = ExportInfo {
            class_names: &["person", "animal", "vehicle"],
            description: "test",
        };
        let model = export(&net, width, height, &info).unwrap();
        let detector = OnnxDetector::from_bytes(&model.encode_to_vec(), width, height).unwrap();
        let (output, shape) = detector.run(&input).unwrap();
        assert_eq!(shape, vec![1, 300, 8]);
        assert_eq!(output.len(), expected.len());
        let mut worst = 0f32;
        for (a, b) in output.iter().zip(&expected) {
            // Relative for the exp-decoded sizes, which can be large.
            worst = worst.max((a - b).abs() / b.abs().max(1.0));
        }
        assert!(worst < 1e-4, "largest difference {worst}");
        // The output is not trivially constant: boxes spread over the grid, scores vary.
        let spread = |attribute: usize| {
            let values: Vec<f32> = output.chunks(8).map(|c| c[attribute]).collect();
            let max = values.iter().copied().fold(f32::MIN, f32::max);
            let min = values.iter().copied().fold(f32::MAX, f32::min);
            max - min
        };
        assert!(spread(0) > 250.0 && spread(1) > 180.0, "centres");
        assert!(spread(4) > 0.1 && spread(2) > 1.0, "scores and sizes");
    }

    #[test]
    fn an_input_off_the_grid_is_a_named_error() {
        let net = HazardNet::new(NetConfig::standard(), 1, &Device::Cpu).unwrap();
        let info = ExportInfo {
            class_names: &[],
            description: "",
        };
        assert!(matches!(
            export(&net, 320, 250, &info),
            Err(ExportError::InputSize {
                width_px: 320,
                height_px: 250
            })
        ));
    }
}
