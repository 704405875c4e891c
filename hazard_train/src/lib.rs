//! Trains the hazard detector the runtime ships (`models/hazard_yolo.onnx`) on frames the
//! simulator renders, and exports it as ONNX with the YOLO decode inside the graph.
//!
//! - [`model`]: the network in candle and its decode;
//! - [`conv`], [`norm`]: the convolution, and the batch normalisation with its activation, that
//!   it trains with: custom operations with fast gradients;
//! - [`target`]: labels → grid-cell targets, and the loss;
//! - [`dataset`]: rendering the training set, random crops and flips;
//! - [`train`]: the optimisation loop;
//! - [`onnx_export`]: the ONNX graph;
//! - [`evaluate`]: precision and recall of an ONNX file on held-out frames, through tract.

pub mod conv;
pub mod dataset;
pub mod evaluate;
pub mod model;
pub mod norm;
pub mod onnx_export;
pub mod target;
pub mod train;
