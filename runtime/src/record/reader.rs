//! Reading a recording back: its header, its config files and its messages, as far as the file
//! is whole (a recording cut off by a crash reads up to its last complete chunk).

use super::{
    ConfigFile, RecordError, RecordingHeader, CONTINUES_METADATA, FORMAT_VERSION, HEADER_METADATA,
};
use mcap::records::Record;
use mcap::sans_io::linear_reader;
use std::collections::HashMap;
use std::io::{Read, Seek};

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
    /// The next part's file, where this is a part of a split recording read alone.
    pub continues_in: Option<String>,
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

/// A recording read as a stream, one chunk at a time: its header and config files at once, then
/// its messages in file order, so a replay holds only what it needs of a long flight. The
/// iterator ends at the file's end, or at its last complete chunk where the file was cut off
/// ([`RecordingReader::truncated`] then says why).
pub struct RecordingReader<R: Read> {
    pub header: RecordingHeader,
    pub config_files: Vec<ConfigFile>,
    records: Records<R>,
    /// The first message, read while looking for the header.
    first: Option<RecordedMessage>,
    /// Where a split recording's next part is opened from (read from a file: its folder).
    parts: Option<NextParts<R>>,
    /// The part being read.
    part: u32,
    /// Where the recording goes on, when a part read from memory ends.
    continues_in: Option<String>,
}

/// How a recording read from a file follows its parts.
struct NextParts<R> {
    folder: std::path::PathBuf,
    open: fn(&std::path::Path) -> Result<R, RecordError>,
}

/// The file's records as they are read.
struct Records<R: Read> {
    source: R,
    reader: linear_reader::LinearReader,
    /// Each channel's topic, by its id.
    topics: HashMap<u16, String>,
    /// Anything of an MCAP file read: before that, an error means the file is none.
    started: bool,
    truncated: Option<String>,
    ended: bool,
}

/// What the stream yields next.
enum Next {
    Message(RecordedMessage),
    Header(Box<RecordingHeader>),
    Config(ConfigFile),
    /// The end of a part: the file the recording goes on in.
    Continues(String),
    Other,
}

impl<R: Read> RecordingReader<R> {
    /// Reads up to the first message: the header (refused where it is missing or of another
    /// format) and the config files.
    pub fn new(source: R) -> Result<Self, RecordError> {
        let (header, config_files, records, first) = Self::start(source)?;
        Ok(Self {
            part: header.part,
            header,
            config_files,
            records,
            first,
            parts: None,
            continues_in: None,
        })
    }

    /// A file's header, config files and first message.
    #[allow(clippy::type_complexity)]
    fn start(
        source: R,
    ) -> Result<
        (
            RecordingHeader,
            Vec<ConfigFile>,
            Records<R>,
            Option<RecordedMessage>,
        ),
        RecordError,
    > {
        let mut records = Records {
            source,
            reader: linear_reader::LinearReader::new_with_options(
                linear_reader::LinearReaderOptions::default().with_skip_end_magic(true),
            ),
            topics: HashMap::new(),
            started: false,
            truncated: None,
            ended: false,
        };
        let mut header = None;
        let mut config_files = Vec::new();
        let mut first = None;
        while let Some(next) = records.next_record()? {
            match next {
                Next::Header(parsed) => header = Some(*parsed),
                Next::Config(file) => config_files.push(file),
                Next::Message(message) => {
                    first = Some(message);
                    break;
                }
                // A part ends after a step, so it holds messages before it says where it goes on.
                Next::Continues(_) | Next::Other => {}
            }
        }
        let header = header.ok_or_else(|| {
            RecordError::NotARecording(
                "no qosrt header (an MCAP file from another program?)".into(),
            )
        })?;
        Ok((header, config_files, records, first))
    }

    /// The part after the one just read, where the recording goes on in `file`: the same
    /// recording's next part, or why not.
    fn next_part(&mut self, file: &str) -> Result<(), String> {
        let parts = self.parts.as_ref().ok_or("it was not read from a file")?;
        if std::path::Path::new(file).components().count() != 1 {
            return Err(format!("{file:?} is not a file name"));
        }
        let source = (parts.open)(&parts.folder.join(file)).map_err(|e| e.to_string())?;
        let (header, _, records, first) = Self::start(source).map_err(|e| e.to_string())?;
        let expected = self.part + 1;
        if header.part != expected || header.recording_id != self.header.recording_id {
            return Err(format!(
                "it is not part {expected} of this recording (part {} of {})",
                header.part,
                if header.recording_id.is_empty() {
                    "another"
                } else {
                    &header.recording_id
                }
            ));
        }
        (self.records, self.first, self.part) = (records, first, expected);
        Ok(())
    }

    /// Why the file ended before its end, once the messages are read.
    pub fn truncated(&self) -> Option<&str> {
        self.records.truncated.as_deref()
    }
}

impl<R: Read> Records<R> {
    /// The next record that matters; `None` at the end of the file, or where it was cut off.
    /// Only a file that is not a recording at all is an error.
    fn next_record(&mut self) -> Result<Option<Next>, RecordError> {
        if self.ended {
            return Ok(None);
        }
        loop {
            let event = match self.reader.next_event() {
                None => {
                    self.ended = true;
                    return Ok(None);
                }
                Some(Err(error)) => {
                    self.ended = true;
                    if !self.started {
                        return Err(RecordError::NotARecording(format!(
                            "not a readable MCAP file: {error}"
                        )));
                    }
                    self.truncated = Some(error.to_string());
                    return Ok(None);
                }
                Some(Ok(event)) => event,
            };
            let (opcode, data) = match event {
                linear_reader::LinearReadEvent::ReadRequest(need) => {
                    let read = self
                        .source
                        .read(self.reader.insert(need))
                        .map_err(RecordError::Io)?;
                    self.reader.notify_read(read);
                    continue;
                }
                linear_reader::LinearReadEvent::Record { opcode, data } => (opcode, data),
            };
            self.started = true;
            let record = match mcap::parse_record(opcode, data) {
                Ok(record) => record,
                Err(error) => {
                    self.ended = true;
                    self.truncated = Some(error.to_string());
                    return Ok(None);
                }
            };
            return Ok(Some(match record {
                Record::Channel(channel) => {
                    self.topics.insert(channel.id, channel.topic);
                    Next::Other
                }
                Record::Message { header, data } => Next::Message(RecordedMessage {
                    topic: self
                        .topics
                        .get(&header.channel_id)
                        .cloned()
                        .unwrap_or_default(),
                    log_time_ns: header.log_time,
                    publish_time_ns: header.publish_time,
                    sequence: header.sequence,
                    data: data.into_owned(),
                }),
                Record::Metadata(metadata) if metadata.name == HEADER_METADATA => {
                    Next::Header(Box::new(parse_header(&metadata.metadata)?))
                }
                Record::Metadata(metadata) if metadata.name == CONTINUES_METADATA => {
                    Next::Continues(metadata.metadata.get("file").cloned().unwrap_or_default())
                }
                Record::Attachment { header, data, .. } => Next::Config(ConfigFile {
                    path: header.name,
                    data: data.into_owned(),
                }),
                _ => Next::Other,
            }));
        }
    }
}

impl<R: Read> Iterator for RecordingReader<R> {
    type Item = RecordedMessage;

    fn next(&mut self) -> Option<RecordedMessage> {
        if let Some(first) = self.first.take() {
            return Some(first);
        }
        loop {
            match self.records.next_record() {
                Ok(Some(Next::Message(message))) => return Some(message),
                Ok(Some(Next::Continues(file))) => {
                    if self.parts.is_none() {
                        // Read from memory: this part is all there is to read.
                        self.continues_in = Some(file);
                        return None;
                    }
                    if let Err(why) = self.next_part(&file) {
                        self.records.truncated =
                            Some(format!("the recording goes on in {file}, unread: {why}"));
                        return None;
                    }
                    if let Some(first) = self.first.take() {
                        return Some(first);
                    }
                }
                Ok(Some(_)) => continue,
                Ok(None) => return None,
                Err(error) => {
                    self.records.truncated = Some(error.to_string());
                    return None;
                }
            }
        }
    }
}

impl RecordingReader<std::io::BufReader<std::fs::File>> {
    /// Opens `path` as a recording.
    /// Opens `path` as a recording; where a size budget split it, the messages go on through
    /// every part.
    pub fn open(path: &std::path::Path) -> Result<Self, RecordError> {
        let mut reader = Self::new(open_file(path)?)?;
        reader.parts = Some(NextParts {
            folder: path
                .parent()
                .unwrap_or(std::path::Path::new(""))
                .to_path_buf(),
            open: open_file,
        });
        Ok(reader)
    }
}

/// A recording's file, checked to be MCAP.
fn open_file(path: &std::path::Path) -> Result<std::io::BufReader<std::fs::File>, RecordError> {
    let read_error = |source| RecordError::Read {
        path: path.to_path_buf(),
        source,
    };
    let mut file = std::fs::File::open(path).map_err(read_error)?;
    let mut magic = [0u8; 8];
    let magic_len = file.read(&mut magic).map_err(read_error)?;
    check_magic(&magic[..magic_len])?;
    file.rewind().map_err(read_error)?;
    Ok(std::io::BufReader::with_capacity(1 << 20, file))
}

impl<R: Read> RecordingReader<R> {
    /// The part being read (0: the first).
    pub fn part(&self) -> u32 {
        self.part
    }
}

fn check_magic(bytes: &[u8]) -> Result<(), RecordError> {
    if bytes.starts_with(mcap::MAGIC) {
        Ok(())
    } else {
        Err(RecordError::NotARecording(
            "not an MCAP file (it does not begin with MCAP's magic bytes)".into(),
        ))
    }
}

fn parse_header(
    metadata: &std::collections::BTreeMap<String, String>,
) -> Result<RecordingHeader, RecordError> {
    let json = metadata
        .get("header")
        .ok_or_else(|| RecordError::NotARecording("the qosrt metadata has no header".into()))?;
    let parsed: RecordingHeader = serde_json::from_str(json)
        .map_err(|e| RecordError::NotARecording(format!("its header does not parse: {e}")))?;
    if parsed.format_version != FORMAT_VERSION {
        return Err(RecordError::NotARecording(format!(
            "format version {} (this build reads {FORMAT_VERSION})",
            parsed.format_version
        )));
    }
    Ok(parsed)
}

/// Reads a recording from its bytes, whole.
pub fn read_recording(bytes: &[u8]) -> Result<Recording, RecordError> {
    check_magic(bytes)?;
    collect(RecordingReader::new(bytes)?)
}

/// Every message of a stream, in memory.
fn collect<R: Read>(mut stream: RecordingReader<R>) -> Result<Recording, RecordError> {
    let messages = stream.by_ref().collect();
    Ok(Recording {
        truncated: stream.records.truncated.take(),
        continues_in: stream.continues_in.take(),
        header: stream.header,
        config_files: stream.config_files,
        messages,
    })
}

/// Reads `path` as a recording, whole (a replay streams it: [`RecordingReader::open`]).
pub fn read_recording_file(path: &std::path::Path) -> Result<Recording, RecordError> {
    collect(RecordingReader::open(path)?)
}
