//! One message, encoded for its channel, on its way to the file and the live view.

use super::channels::ChannelSpec;
use algorithms::vision::image::GrayImage;
use std::sync::Arc;

/// One message, encoded, on its way to the file.
pub struct Encoded {
    pub spec: ChannelSpec,
    pub log_time_ns: u64,
    pub publish_time_ns: u64,
    /// The MCAP sequence number; `None`: the channel's count.
    pub sequence: Option<u32>,
    pub data: Vec<u8>,
    /// A camera frame the file holds in the compact codec, which no viewer reads: the live view
    /// sends its pixels as PNG (made from them, not decoded from `data`).
    pub viewer_frame: Option<Arc<GrayImage>>,
}

impl Encoded {
    pub fn at(spec: ChannelSpec, time_ns: u64, data: Vec<u8>) -> Self {
        Self {
            spec,
            log_time_ns: time_ns,
            publish_time_ns: time_ns,
            sequence: None,
            data,
            viewer_frame: None,
        }
    }
}
