//! One message, encoded for its channel, on its way to the file and the live view.

use super::channels::ChannelSpec;

/// One message, encoded, on its way to the file.
pub struct Encoded {
    pub spec: ChannelSpec,
    pub log_time_ns: u64,
    pub publish_time_ns: u64,
    /// The MCAP sequence number; `None`: the channel's count.
    pub sequence: Option<u32>,
    pub data: Vec<u8>,
}

impl Encoded {
    pub fn at(spec: ChannelSpec, time_ns: u64, data: Vec<u8>) -> Self {
        Self {
            spec,
            log_time_ns: time_ns,
            publish_time_ns: time_ns,
            sequence: None,
            data,
        }
    }
}
