//! Tracking by detection (seed 000, §2.2.1): optimal assignment, box overlap, colour histograms
//! and the multi-target tracker that removes false alarms.

pub mod histogram;
pub mod hungarian;
pub mod iou;
pub mod tracker;
