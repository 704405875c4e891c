//! The recording's MCAP file: its channels, its header, and the size budget
//! (`--record-max-mb`) that ends a file at a step of the loop and goes on in the next part
//! (`flight.mcap`, `flight-1.mcap`, …), each a whole MCAP file with the header and the config.

use super::channels as ch;
use super::encoded::Encoded;
use super::{ConfigFile, RecordError, RecordingHeader, CONTINUES_METADATA, HEADER_METADATA};
use std::collections::{BTreeMap, HashMap};
use std::io::{BufWriter, Cursor, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// Where the MCAP bytes go.
pub(super) enum Output {
    /// A file, and the bytes handed to it so far.
    File(BufWriter<std::fs::File>, Arc<AtomicU64>),
    Memory(Cursor<Vec<u8>>),
    /// Live only.
    None,
}

impl Output {
    pub fn create(path: &Path) -> Result<Self, RecordError> {
        let file = std::fs::File::create(path).map_err(|source| RecordError::Create {
            path: path.to_path_buf(),
            source,
        })?;
        Ok(Output::File(BufWriter::new(file), Arc::default()))
    }
}

impl Write for Output {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        match self {
            Output::File(f, written) => {
                let n = f.write(buf)?;
                written.fetch_add(n as u64, Ordering::Relaxed);
                Ok(n)
            }
            Output::Memory(m) => m.write(buf),
            Output::None => Ok(buf.len()),
        }
    }
    fn flush(&mut self) -> std::io::Result<()> {
        match self {
            Output::File(f, _) => f.flush(),
            Output::Memory(m) => m.flush(),
            Output::None => Ok(()),
        }
    }
}

impl Seek for Output {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        match self {
            Output::File(f, _) => f.seek(pos),
            Output::Memory(m) => m.seek(pos),
            Output::None => Ok(0),
        }
    }
}

/// What a finished recording holds.
#[derive(Debug, Clone, Default)]
pub struct RecordingSummary {
    pub file: Option<PathBuf>,
    /// Messages per topic.
    pub messages: BTreeMap<String, u64>,
    /// Bytes, of every part.
    pub bytes: u64,
    /// Every file, in order, where a size budget split the recording.
    pub parts: Vec<PathBuf>,
    /// The file itself, when kept in memory.
    pub data: Option<Vec<u8>>,
}

impl RecordingSummary {
    pub fn total_messages(&self) -> u64 {
        self.messages.values().sum()
    }

    /// What the run says of its recording: messages, size, and where.
    pub fn describe(&self) -> String {
        let mut text = format!(
            "recorded {} messages ({:.1} MB)",
            self.total_messages(),
            self.bytes as f64 / 1e6
        );
        if let Some(file) = &self.file {
            text += &format!(" to {}", file.display());
        }
        if let [_, .., last] = &self.parts[..] {
            text += &format!(" in {} parts, to {}", self.parts.len(), last.display());
        }
        text
    }
}

/// The file name of part `index` of the recording whose first file is `first`.
pub fn part_path(first: &Path, index: u32) -> PathBuf {
    if index == 0 {
        return first.to_path_buf();
    }
    let stem = first
        .file_stem()
        .map_or("recording".into(), |s| s.to_string_lossy());
    let name = match first.extension() {
        Some(extension) => format!("{stem}-{index}.{}", extension.to_string_lossy()),
        None => format!("{stem}-{index}"),
    };
    first.with_file_name(name)
}

/// A size budget per file, and what a new part needs.
struct Split {
    max_bytes: u64,
    first: PathBuf,
    header: RecordingHeader,
    config_files: Vec<ConfigFile>,
    /// Bytes handed to the current file, and message bytes since that count last moved (at
    /// most the chunk the writer still holds, before its compression).
    written: Arc<AtomicU64>,
    written_seen: u64,
    unflushed: u64,
}

impl Split {
    /// A file ends at a step once it may hold 90 % of its budget: the next step's messages
    /// and the file's summary fit in the rest.
    fn full(&mut self) -> bool {
        let written = self.written.load(Ordering::Relaxed);
        if written != self.written_seen {
            (self.written_seen, self.unflushed) = (written, 0);
        }
        (written + self.unflushed) * 10 >= self.max_bytes * 9
    }
}

/// The MCAP writer with its channels.
pub(super) struct McapSink {
    writer: Option<mcap::Writer<Output>>,
    path: Option<PathBuf>,
    channel_ids: HashMap<&'static str, u16>,
    sequences: HashMap<&'static str, u32>,
    counts: BTreeMap<String, u64>,
    split: Option<Split>,
    /// The parts finished so far, and their bytes.
    parts: Vec<(PathBuf, u64)>,
}

fn mcap_writer(output: Output) -> Result<mcap::Writer<Output>, RecordError> {
    mcap::WriteOptions::new()
        .profile("qosrt")
        .library(concat!("qosrt ", env!("CARGO_PKG_VERSION")))
        .compression(Some(mcap::Compression::Zstd))
        .compression_level(1)
        // Compression on this thread: the mission's cores stay with the tasks.
        .compression_threads(0)
        .create(output)
        .map_err(RecordError::Mcap)
}

impl McapSink {
    /// A sink writing `output`, which holds `path` (if a file); `max_bytes` splits it.
    pub fn new(
        output: Output,
        path: Option<PathBuf>,
        header: &RecordingHeader,
        config_files: &[ConfigFile],
        max_bytes: Option<u64>,
    ) -> Result<Self, RecordError> {
        let split = match (&output, &path, max_bytes) {
            (Output::File(_, written), Some(first), Some(max_bytes)) => Some(Split {
                max_bytes,
                first: first.clone(),
                header: header.clone(),
                config_files: config_files.to_vec(),
                written: written.clone(),
                written_seen: 0,
                unflushed: 0,
            }),
            _ => None,
        };
        let writer = match output {
            Output::None => None,
            output => Some(mcap_writer(output)?),
        };
        let mut sink = Self {
            writer,
            path,
            channel_ids: HashMap::new(),
            sequences: HashMap::new(),
            counts: BTreeMap::new(),
            split,
            parts: Vec::new(),
        };
        sink.header(header, config_files)?;
        Ok(sink)
    }

    /// The run's header (metadata) and the config files it flew (attachments).
    fn header(
        &mut self,
        header: &RecordingHeader,
        config_files: &[ConfigFile],
    ) -> Result<(), RecordError> {
        let Some(writer) = &mut self.writer else {
            return Ok(());
        };
        let json = serde_json::to_string(header).expect("the header serialises");
        writer
            .write_metadata(&mcap::records::Metadata {
                name: HEADER_METADATA.into(),
                metadata: BTreeMap::from([("header".to_string(), json)]),
            })
            .map_err(RecordError::Mcap)?;
        for file in config_files {
            writer
                .attach(&mcap::Attachment {
                    log_time: 0,
                    create_time: 0,
                    name: file.path.clone(),
                    media_type: "application/toml".into(),
                    data: std::borrow::Cow::Borrowed(&file.data),
                })
                .map_err(RecordError::Mcap)?;
        }
        Ok(())
    }

    pub fn write(&mut self, message: &Encoded) -> Result<(), RecordError> {
        let topic = message.spec.topic;
        let count = self.counts.entry(topic.to_string()).or_default();
        *count += 1;
        let Some(writer) = &mut self.writer else {
            return Ok(());
        };
        let channel_id = match self.channel_ids.get(topic) {
            Some(&id) => id,
            None => {
                let schema = message.spec.schema();
                let schema_id = writer
                    .add_schema(&schema.name, &schema.encoding, &schema.data)
                    .map_err(RecordError::Mcap)?;
                let id = writer
                    .add_channel(
                        schema_id,
                        topic,
                        message.spec.message_encoding(),
                        &BTreeMap::new(),
                    )
                    .map_err(RecordError::Mcap)?;
                self.channel_ids.insert(topic, id);
                id
            }
        };
        let next = self.sequences.entry(topic).or_default();
        *next += 1;
        writer
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id,
                    sequence: message.sequence.unwrap_or(*next),
                    log_time: message.log_time_ns,
                    publish_time: message.publish_time_ns,
                },
                &message.data,
            )
            .map_err(RecordError::Mcap)?;
        if let Some(split) = &mut self.split {
            split.unflushed += message.data.len() as u64;
            // A file ends after a step: the next begins with the next step's inputs.
            if topic == ch::STEP.topic && split.full() {
                self.next_part(message.log_time_ns)?;
            }
        }
        Ok(())
    }

    /// Ends this file, saying where the recording goes on, and opens the next part.
    fn next_part(&mut self, after_ns: u64) -> Result<(), RecordError> {
        let (Some(split), Some(mut writer)) = (&mut self.split, self.writer.take()) else {
            return Ok(());
        };
        let index = self.parts.len() as u32 + 1;
        let next = part_path(&split.first, index);
        let name = next.file_name().map(|n| n.to_string_lossy().into_owned());
        writer
            .write_metadata(&mcap::records::Metadata {
                name: CONTINUES_METADATA.into(),
                metadata: BTreeMap::from([("file".to_string(), name.unwrap_or_default())]),
            })
            .map_err(RecordError::Mcap)?;
        let bytes = finish_file(writer)?;
        let done = self.path.replace(next.clone()).unwrap_or_default();
        self.parts.push((done, bytes));
        let output = Output::create(&next)?;
        if let Output::File(_, written) = &output {
            (split.written, split.written_seen, split.unflushed) = (written.clone(), 0, 0);
        }
        let header = RecordingHeader {
            part: index,
            first_part: split
                .first
                .file_name()
                .map(|n| n.to_string_lossy().into_owned()),
            part_starts_ns: Some(after_ns),
            ..split.header.clone()
        };
        let config_files = split.config_files.clone();
        self.writer = Some(mcap_writer(output)?);
        // A new file declares its schemas and channels again.
        self.channel_ids.clear();
        self.header(&header, &config_files)
    }

    /// Closes the chunk: everything so far stays readable if the process dies.
    pub fn flush(&mut self) -> Result<(), RecordError> {
        match &mut self.writer {
            Some(writer) => writer.flush().map_err(RecordError::Mcap),
            None => Ok(()),
        }
    }

    pub fn finish(mut self) -> Result<RecordingSummary, RecordError> {
        let mut summary = RecordingSummary {
            file: self
                .split
                .as_ref()
                .map(|s| s.first.clone())
                .or(self.path.clone()),
            messages: std::mem::take(&mut self.counts),
            ..RecordingSummary::default()
        };
        if let Some(mut writer) = self.writer.take() {
            writer.finish().map_err(RecordError::Mcap)?;
            match writer.into_inner() {
                Output::File(file, _) => {
                    let bytes = file_bytes(file)?;
                    self.parts
                        .push((self.path.clone().unwrap_or_default(), bytes));
                }
                Output::Memory(memory) => {
                    let data = memory.into_inner();
                    summary.bytes = data.len() as u64;
                    summary.data = Some(data);
                }
                Output::None => {}
            }
        }
        summary.bytes += self.parts.iter().map(|(_, bytes)| bytes).sum::<u64>();
        summary.parts = self.parts.into_iter().map(|(path, _)| path).collect();
        Ok(summary)
    }
}

/// Finishes a file's writer (its summary and index), and says how many bytes it holds.
fn finish_file(mut writer: mcap::Writer<Output>) -> Result<u64, RecordError> {
    writer.finish().map_err(RecordError::Mcap)?;
    match writer.into_inner() {
        Output::File(file, _) => file_bytes(file),
        _ => Ok(0),
    }
}

/// Writes what is buffered and says how long the file is.
fn file_bytes(file: BufWriter<std::fs::File>) -> Result<u64, RecordError> {
    let file = file
        .into_inner()
        .map_err(|e| RecordError::Io(e.into_error()))?;
    file.metadata().map(|m| m.len()).map_err(RecordError::Io)
}
