//! Reading a recording back: its header, its config files and its messages, as far as the file
//! is whole (a recording cut off by a crash reads up to its last complete chunk).

use super::{ConfigFile, RecordError, RecordingHeader, FORMAT_VERSION, HEADER_METADATA};
use mcap::read::{LinearReader, MessageStream, Options};
use mcap::records::Record;

/// One recorded message.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedMessage {
    pub topic: String,
    pub log_time_ns: u64,
    pub publish_time_ns: u64,
    pub sequence: u32,
    pub data: Vec<u8>,
}

/// A recording, in file order.
#[derive(Debug, Clone)]
pub struct Recording {
    pub header: RecordingHeader,
    pub config_files: Vec<ConfigFile>,
    pub messages: Vec<RecordedMessage>,
    /// Why the file ended before its end: the last complete message was read, the rest lost.
    pub truncated: Option<String>,
}

impl Recording {
    /// The messages of one topic, in order.
    pub fn topic<'a>(&'a self, topic: &'a str) -> impl Iterator<Item = &'a RecordedMessage> + 'a {
        self.messages.iter().filter(move |m| m.topic == topic)
    }

    /// The time of the last message, in seconds.
    pub fn end_s(&self) -> f64 {
        self.messages
            .iter()
            .map(|m| m.log_time_ns)
            .max()
            .unwrap_or(0) as f64
            / 1e9
    }
}

/// Reads a recording from its bytes.
pub fn read_recording(bytes: &[u8]) -> Result<Recording, RecordError> {
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(RecordError::NotARecording(
            "not an MCAP file (it does not begin with MCAP's magic bytes)".into(),
        ));
    }
    let mut header = None;
    let mut config_files = Vec::new();
    let records = LinearReader::new_with_options(bytes, Options::IgnoreEndMagic.into())
        .map_err(RecordError::Mcap)?;
    // The header and the config files come first; a cut-off file still has them.
    for record in records {
        match record {
            Ok(Record::Metadata(metadata)) if metadata.name == HEADER_METADATA => {
                let json = metadata.metadata.get("header").ok_or_else(|| {
                    RecordError::NotARecording("the qosrt metadata has no header".into())
                })?;
                let parsed: RecordingHeader = serde_json::from_str(json).map_err(|e| {
                    RecordError::NotARecording(format!("its header does not parse: {e}"))
                })?;
                if parsed.format_version != FORMAT_VERSION {
                    return Err(RecordError::NotARecording(format!(
                        "format version {} (this build reads {FORMAT_VERSION})",
                        parsed.format_version
                    )));
                }
                header = Some(parsed);
            }
            Ok(Record::Attachment { header, data, .. }) => config_files.push(ConfigFile {
                path: header.name,
                data: data.into_owned(),
            }),
            Ok(Record::Chunk { .. } | Record::Message { .. }) | Err(_) => break,
            Ok(_) => {}
        }
    }
    let header = header.ok_or_else(|| {
        RecordError::NotARecording("no qosrt header (an MCAP file from another program?)".into())
    })?;
    let mut messages = Vec::new();
    let mut truncated = None;
    let stream = MessageStream::new_with_options(bytes, Options::IgnoreEndMagic.into())
        .map_err(RecordError::Mcap)?;
    for message in stream {
        match message {
            Ok(message) => messages.push(RecordedMessage {
                topic: message.channel.topic.clone(),
                log_time_ns: message.log_time,
                publish_time_ns: message.publish_time,
                sequence: message.sequence,
                data: message.data.into_owned(),
            }),
            Err(error) => {
                truncated = Some(error.to_string());
                break;
            }
        }
    }
    Ok(Recording {
        header,
        config_files,
        messages,
        truncated,
    })
}

/// Reads `path` as a recording.
pub fn read_recording_file(path: &std::path::Path) -> Result<Recording, RecordError> {
    let bytes = std::fs::read(path).map_err(|source| RecordError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    read_recording(&bytes)
}
