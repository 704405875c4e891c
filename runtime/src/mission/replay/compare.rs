//! A replay's outputs against the recording's, channel by channel, without holding either in
//! memory: each output message is kept as its time and a 128-bit fingerprint of its bytes, and
//! only a channel's first differing pair is read back whole, to name the fields that differ.

use super::ChannelDiff;
use crate::record::channels::{self as ch, Role};
use crate::record::reader::{RecordedMessage, RecordingReader};
use crate::record::RecordError;
use std::collections::{BTreeMap, BTreeSet};
use std::hash::Hasher;
use std::path::Path;

/// One message as compared: its time and the fingerprint of its bytes.
type Print = (u64, u128);

/// The output channels of a recording, as fingerprints in order.
#[derive(Debug, Default)]
pub struct OutputPrints {
    channels: BTreeMap<String, Vec<Print>>,
}

impl OutputPrints {
    /// Keeps `message` if it is on an output channel.
    pub fn add(&mut self, message: &RecordedMessage) {
        if ch::channel(&message.topic).is_some_and(|c| c.role == Role::Output) {
            self.channels
                .entry(message.topic.clone())
                .or_default()
                .push((message.log_time_ns, fingerprint(&message.data)));
        }
    }

    /// Every output message of a recording file, streamed.
    pub fn of_file(path: &Path) -> Result<Self, RecordError> {
        let mut prints = Self::default();
        for message in RecordingReader::open(path)? {
            prints.add(&message);
        }
        Ok(prints)
    }

    fn upto(&self, topic: &str, until_ns: u64) -> &[Print] {
        let prints = self.channels.get(topic).map_or(&[][..], Vec::as_slice);
        // Messages come in time order on a channel.
        let end = prints.partition_point(|&(time_ns, _)| time_ns <= until_ns);
        &prints[..end]
    }
}

/// Two SipHash-1-3 passes (std's fixed-key hasher), each begun with its own prefix: 128 bits,
/// so two different messages share a fingerprint with a chance of about 2^-128.
fn fingerprint(bytes: &[u8]) -> u128 {
    let half = |prefix: u64| {
        let mut hasher = std::hash::DefaultHasher::new();
        hasher.write_u64(prefix);
        hasher.write(bytes);
        hasher.finish()
    };
    (u128::from(half(0x7172_7374_7265_706c)) << 64) | u128::from(half(0x6d63_6170_2d66_7031))
}

/// Every output channel of either side compared message by message up to `until_ns`; the
/// first difference of each is named by reading its two messages back (`read_back`: the
/// recorded and the replayed message at those indices, by topic).
pub fn compare(
    recorded: &OutputPrints,
    replayed: &OutputPrints,
    until_ns: u64,
    read_back: impl FnOnce(
        &BTreeMap<String, usize>,
    ) -> Result<
        (
            BTreeMap<String, RecordedMessage>,
            BTreeMap<String, RecordedMessage>,
        ),
        RecordError,
    >,
) -> Result<Vec<ChannelDiff>, RecordError> {
    let topics: BTreeSet<&String> = recorded
        .channels
        .keys()
        .chain(replayed.channels.keys())
        .collect();
    let mut diffs = Vec::new();
    let mut first_at = BTreeMap::new();
    for topic in topics {
        let (diff, first) = diff_prints(
            topic,
            recorded.upto(topic, until_ns),
            replayed.upto(topic, until_ns),
        );
        if let Some(index) = first {
            first_at.insert(topic.clone(), index);
        }
        diffs.push(diff);
    }
    if !first_at.is_empty() {
        let (recorded_messages, replayed_messages) = read_back(&first_at)?;
        for diff in &mut diffs {
            if first_at.contains_key(&diff.topic) {
                diff.first_fields = fields_of(
                    recorded_messages.get(&diff.topic),
                    replayed_messages.get(&diff.topic),
                );
            }
        }
    }
    Ok(diffs)
}

/// The message at each wanted index of its topic, from a recording file, streamed.
pub fn messages_at(
    path: &Path,
    wanted: &BTreeMap<String, usize>,
) -> Result<BTreeMap<String, RecordedMessage>, RecordError> {
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    let mut found = BTreeMap::new();
    for message in RecordingReader::open(path)? {
        let Some(&index) = wanted.get(&message.topic) else {
            continue;
        };
        let count = seen.entry(message.topic.clone()).or_default();
        if *count == index {
            found.insert(message.topic.clone(), message);
            if found.len() == wanted.len() {
                break;
            }
        }
        *count += 1;
    }
    Ok(found)
}

/// How two channels' messages differ, pair by pair (by order), and the index of the first
/// pair that does.
fn diff_prints(
    topic: &str,
    recorded: &[Print],
    replayed: &[Print],
) -> (ChannelDiff, Option<usize>) {
    let mut diff = ChannelDiff {
        topic: topic.to_string(),
        recorded: recorded.len(),
        replayed: replayed.len(),
        differing: 0,
        first_difference_s: None,
        last_difference_s: None,
        first_fields: Vec::new(),
    };
    let mut first = None;
    for index in 0..recorded.len().max(replayed.len()) {
        let (a, b) = (recorded.get(index), replayed.get(index));
        if matches!((a, b), (Some(a), Some(b)) if a == b) {
            continue;
        }
        diff.differing += 1;
        let time_s = a.or(b).map_or(0, |&(time_ns, _)| time_ns) as f64 * 1e-9;
        diff.last_difference_s = Some(time_s);
        if first.is_none() {
            first = Some(index);
            diff.first_difference_s = Some(time_s);
        }
    }
    (diff, first)
}

/// The fields of a differing pair, or which side lacks the message.
fn fields_of(
    recorded: Option<&RecordedMessage>,
    replayed: Option<&RecordedMessage>,
) -> Vec<String> {
    match (recorded, replayed) {
        (Some(a), Some(b)) => field_differences(a, b),
        (Some(_), None) => vec!["(not produced by the replay)".into()],
        _ => vec!["(not in the recording)".into()],
    }
}

/// Two channels of messages in memory, compared as [`compare`] compares files.
#[cfg(test)]
fn diff_channel(
    topic: &str,
    recorded: &[RecordedMessage],
    replayed: &[RecordedMessage],
) -> ChannelDiff {
    let prints = |messages: &[RecordedMessage]| -> Vec<Print> {
        messages
            .iter()
            .map(|m| (m.log_time_ns, fingerprint(&m.data)))
            .collect()
    };
    let (mut diff, first) = diff_prints(topic, &prints(recorded), &prints(replayed));
    if let Some(index) = first {
        diff.first_fields = fields_of(recorded.get(index), replayed.get(index));
    }
    diff
}

/// At most this many fields are named per difference.
const MAX_FIELDS: usize = 6;

/// The fields of two messages that differ, as `path: recorded → replayed` (JSON), or what else
/// differs.
fn field_differences(a: &RecordedMessage, b: &RecordedMessage) -> Vec<String> {
    let mut fields = Vec::new();
    if a.log_time_ns != b.log_time_ns {
        fields.push(format!(
            "time: {:.6} s → {:.6} s",
            a.log_time_ns as f64 * 1e-9,
            b.log_time_ns as f64 * 1e-9
        ));
    }
    match (
        serde_json::from_slice::<serde_json::Value>(&a.data),
        serde_json::from_slice::<serde_json::Value>(&b.data),
    ) {
        (Ok(x), Ok(y)) => json_differences("", &x, &y, &mut fields),
        _ if a.data != b.data => fields.push("(binary message differs)".into()),
        _ => {}
    }
    fields.truncate(MAX_FIELDS);
    fields
}

fn json_differences(
    path: &str,
    a: &serde_json::Value,
    b: &serde_json::Value,
    out: &mut Vec<String>,
) {
    use serde_json::Value;
    if out.len() >= MAX_FIELDS || a == b {
        return;
    }
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let keys: BTreeSet<&String> = x.keys().chain(y.keys()).collect();
            for key in keys {
                let (p, q) = (
                    x.get(key).unwrap_or(&Value::Null),
                    y.get(key).unwrap_or(&Value::Null),
                );
                json_differences(&format!("{path}.{key}"), p, q, out);
            }
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => {
            for (i, (p, q)) in x.iter().zip(y).enumerate() {
                json_differences(&format!("{path}[{i}]"), p, q, out);
            }
        }
        _ => out.push(format!(
            "{}: {} → {}",
            path.strip_prefix('.').unwrap_or(path),
            shortened(a),
            shortened(b)
        )),
    }
}

/// A value as JSON, cut to a readable length.
fn shortened(value: &serde_json::Value) -> String {
    const MAX_CHARS: usize = 60;
    let text = value.to_string();
    match text.char_indices().nth(MAX_CHARS) {
        Some((cut, _)) => format!("{}…", &text[..cut]),
        None => text,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn message(topic: &str, time_ns: u64, json: &str) -> RecordedMessage {
        RecordedMessage {
            topic: topic.into(),
            log_time_ns: time_ns,
            publish_time_ns: time_ns,
            sequence: 0,
            data: json.as_bytes().to_vec(),
        }
    }

    #[test]
    fn a_difference_is_placed_in_time_and_named_by_field() {
        let topic = "/bus/landing/setpoint";
        let recorded = [
            message(
                topic,
                1_000_000_000,
                r#"{"mode":"Descend","v":[0.5,0.0,1.0]}"#,
            ),
            message(
                topic,
                2_000_000_000,
                r#"{"mode":"Descend","v":[0.5,0.1,1.0]}"#,
            ),
            message(
                topic,
                3_000_000_000,
                r#"{"mode":"Final","v":[0.0,0.0,2.0]}"#,
            ),
        ];
        let replayed = [
            message(
                topic,
                1_000_000_000,
                r#"{"mode":"Descend","v":[0.5,0.0,1.0]}"#,
            ),
            message(
                topic,
                2_000_000_000,
                r#"{"mode":"Descend","v":[0.5,0.2,1.0]}"#,
            ),
        ];
        let diff = diff_channel(topic, &recorded, &replayed);
        assert_eq!((diff.recorded, diff.replayed, diff.differing), (3, 2, 2));
        assert_eq!(diff.first_difference_s, Some(2.0));
        assert_eq!(diff.last_difference_s, Some(3.0));
        assert_eq!(diff.first_fields, ["v[1]: 0.1 → 0.2"]);
        let same = diff_channel(topic, &recorded, &recorded);
        assert!(same.identical(), "{same:?}");
    }

    #[test]
    fn a_message_at_another_time_differs_even_with_the_same_content() {
        let topic = "/qosrt/governor";
        let diff = diff_channel(
            topic,
            &[message(topic, 1_000_000_000, "{}")],
            &[message(topic, 1_500_000_000, "{}")],
        );
        assert_eq!(diff.differing, 1);
        assert_eq!(diff.first_fields, ["time: 1.000000 s → 1.500000 s"]);
    }
}
