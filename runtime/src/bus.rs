//! The message bus between tasks: typed, timestamped messages on named topics.
//!
//! Two kinds of topic:
//! - **latest value** (like PX4's uORB): a publisher overwrites the one slot; a subscriber reads
//!   the newest message and can tell whether it is new since it last looked (and, from the
//!   sequence numbers, how many it missed). For state that only matters when fresh: a marker
//!   observation, the relative state, a hazard report.
//! - **queue**: bounded FIFO with one receiver, for streams where every message matters. When
//!   full, the topic's [`Overflow`] policy either drops the oldest message or rejects the new
//!   one; both are counted.
//!
//! A topic is declared once as a [`Topic`] constant, its name and message type together (the
//! built-in ones are in [`crate::topics`]). A name is bound to one type and one kind at first
//! use; asking for it with another type or kind is a named error, never a silent second topic.
//! There is no global state: a [`Bus`] is an object the scheduler hands to its tasks (cloning
//! shares it).

use crate::clock::Timestamp;
use std::any::{type_name, Any, TypeId};
use std::collections::{BTreeMap, VecDeque};
use std::fmt;
use std::marker::PhantomData;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, OnceLock, PoisonError};

mod activity;
pub use activity::TopicActivity;

/// A topic's name and message type, declared once: a publisher and a subscriber made from the
/// same constant cannot disagree on the type, and a plugin's ports name it
/// ([`crate::catalog::Port`]).
pub struct Topic<T> {
    name: &'static str,
    message: &'static str,
    _message: PhantomData<fn() -> T>,
}

impl<T> Topic<T> {
    /// The topic `name` carrying `T`, which `message` names for people (`qosrt check --graph`).
    pub const fn new(name: &'static str, message: &'static str) -> Self {
        Topic {
            name,
            message,
            _message: PhantomData,
        }
    }

    pub const fn name(&self) -> &'static str {
        self.name
    }

    /// The message type's name, as declared.
    pub const fn message(&self) -> &'static str {
        self.message
    }
}

impl<T> Clone for Topic<T> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<T> Copy for Topic<T> {}

impl<T> fmt::Debug for Topic<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ({})", self.name, self.message)
    }
}

/// One message: the value, when it was stamped, and its sequence number on its topic
/// (1 for the first message published, counting every message ever offered).
#[derive(Debug, Clone, PartialEq)]
pub struct Message<T> {
    pub stamp: Timestamp,
    pub seq: u64,
    pub value: T,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TopicKind {
    Latest,
    Queue,
}

impl fmt::Display for TopicKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            TopicKind::Latest => "latest-value",
            TopicKind::Queue => "queue",
        })
    }
}

/// What a full queue does with a new message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Overflow {
    /// Evict the oldest queued message to make room (counted as dropped): the receiver always
    /// sees the most recent `capacity` messages.
    DropOldest,
    /// Refuse the new message (counted as rejected) and hand it back to the sender.
    Reject,
}

/// A queue topic's contract; sender and receiver must agree on it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QueueSpec {
    pub capacity: usize,
    pub overflow: Overflow,
}

impl QueueSpec {
    pub fn drop_oldest(capacity: usize) -> Self {
        QueueSpec {
            capacity,
            overflow: Overflow::DropOldest,
        }
    }

    pub fn reject(capacity: usize) -> Self {
        QueueSpec {
            capacity,
            overflow: Overflow::Reject,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BusError {
    #[error("a topic name must not be empty")]
    EmptyTopicName,
    #[error("topic `{topic}` carries `{existing}`, not `{requested}`")]
    TypeMismatch {
        topic: String,
        existing: &'static str,
        requested: &'static str,
    },
    #[error("topic `{topic}` is a {existing} topic, not a {requested} topic")]
    KindMismatch {
        topic: String,
        existing: TopicKind,
        requested: TopicKind,
    },
    #[error(
        "queue `{topic}` was declared with capacity {} ({:?}), not capacity {} ({:?})",
        existing.capacity, existing.overflow, requested.capacity, requested.overflow
    )]
    QueueSpecMismatch {
        topic: String,
        existing: QueueSpec,
        requested: QueueSpec,
    },
    #[error("queue `{topic}` needs a capacity of at least 1")]
    ZeroCapacity { topic: String },
    #[error("queue `{topic}` already has its receiver; a queue has exactly one")]
    ReceiverTaken { topic: String },
    #[error("topic `{topic}` is already tapped; a topic has at most one tap (one recorder)")]
    AlreadyTapped { topic: String },
}

/// A queue refused a message (its policy is [`Overflow::Reject`] and it is full); here it is back.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct QueueFull<T>(pub T);

/// How a message went into a queue.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sent {
    Queued,
    /// Queued after evicting the oldest message.
    DroppedOldest,
}

/// Counters of one topic, for diagnostics.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicInfo {
    pub name: String,
    pub type_name: &'static str,
    pub kind: TopicKind,
    /// Messages offered to the topic (queued, dropped-oldest and rejected alike).
    pub published: u64,
    /// Queue only: messages evicted by [`Overflow::DropOldest`].
    pub dropped: u64,
    /// Queue only: messages refused by [`Overflow::Reject`].
    pub rejected: u64,
    /// Queue only: messages waiting.
    pub depth: usize,
}

fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panicking task may have held a topic's lock; the data (a slot or a queue) is still
    // consistent because every critical section is a single push/pop/replace.
    mutex.lock().unwrap_or_else(PoisonError::into_inner)
}

trait TopicCounters: Send + Sync {
    fn counters(&self) -> (u64, u64, u64, usize);
}

struct TopicEntry {
    type_id: TypeId,
    type_name: &'static str,
    kind: TopicKind,
    queue_spec: Option<QueueSpec>,
    slot: Arc<dyn Any + Send + Sync>,
    counters: Arc<dyn TopicCounters>,
}

/// The bus: a set of named topics. Clone it to share it.
#[derive(Clone, Default)]
pub struct Bus {
    topics: Arc<Mutex<BTreeMap<String, TopicEntry>>>,
    /// Each topic's activity by name, kept apart from the typed slots so that a task can be
    /// triggered by a topic before (and whatever) its message type is known.
    activities: Arc<Mutex<BTreeMap<String, Arc<TopicActivity>>>>,
}

impl fmt::Debug for Bus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Bus")
            .field("topics", &lock(&self.topics).keys().collect::<Vec<_>>())
            .finish()
    }
}

impl Bus {
    pub fn new() -> Self {
        Self::default()
    }

    /// A publisher on the latest-value topic `topic` (created on first use).
    pub fn publisher<T: Send + Sync + 'static>(
        &self,
        topic: Topic<T>,
    ) -> Result<Publisher<T>, BusError> {
        Ok(Publisher {
            slot: self.latest_slot::<T>(topic.name)?,
        })
    }

    /// A subscriber to the latest-value topic `topic` (created on first use). It has seen
    /// nothing yet: a message already on the topic counts as new.
    pub fn subscriber<T: Send + Sync + 'static>(
        &self,
        topic: Topic<T>,
    ) -> Result<Subscriber<T>, BusError> {
        Ok(Subscriber {
            slot: self.latest_slot::<T>(topic.name)?,
            seen_seq: 0,
        })
    }

    /// A sender on the queue `topic`; the first sender or receiver declares `spec`, later ones
    /// must ask for the same.
    pub fn queue_sender<T: Send + 'static>(
        &self,
        topic: Topic<T>,
        spec: QueueSpec,
    ) -> Result<QueueSender<T>, BusError> {
        Ok(QueueSender {
            queue: self.queue_slot::<T>(topic.name, spec)?,
        })
    }

    /// The one receiver of the queue `topic`; dropping it lets another take its place (a
    /// restarted task), with the messages queued meanwhile still waiting.
    pub fn queue_receiver<T: Send + 'static>(
        &self,
        topic: Topic<T>,
        spec: QueueSpec,
    ) -> Result<QueueReceiver<T>, BusError> {
        let queue = self.queue_slot::<T>(topic.name, spec)?;
        if queue.receiver_taken.swap(true, Ordering::AcqRel) {
            return Err(BusError::ReceiverTaken {
                topic: topic.name.to_string(),
            });
        }
        Ok(QueueReceiver { queue })
    }

    /// Hands every message published on the latest-value topic `topic` from now on to `tap`,
    /// on the publisher's thread, in publication order (a recorder: the tap only queues the
    /// message for its own thread).
    pub fn tap<T: Send + Sync + 'static>(
        &self,
        topic: Topic<T>,
        tap: Tap<T>,
    ) -> Result<(), BusError> {
        self.latest_slot::<T>(topic.name)?
            .tap
            .set(tap)
            .map_err(|_| BusError::AlreadyTapped {
                topic: topic.name.to_string(),
            })
    }

    /// Every topic with its counters, by name.
    pub fn topics(&self) -> Vec<TopicInfo> {
        lock(&self.topics)
            .iter()
            .map(|(name, entry)| {
                let (published, dropped, rejected, depth) = entry.counters.counters();
                TopicInfo {
                    name: name.clone(),
                    type_name: entry.type_name,
                    kind: entry.kind,
                    published,
                    dropped,
                    rejected,
                    depth,
                }
            })
            .collect()
    }

    /// The activity of the topic `topic` (created on first use, by either side): what an
    /// input-triggered task watches.
    pub fn activity(&self, topic: &str) -> Result<Arc<TopicActivity>, BusError> {
        if topic.is_empty() {
            return Err(BusError::EmptyTopicName);
        }
        Ok(lock(&self.activities)
            .entry(topic.to_string())
            .or_default()
            .clone())
    }

    fn latest_slot<T: Send + Sync + 'static>(
        &self,
        topic: &str,
    ) -> Result<Arc<LatestSlot<T>>, BusError> {
        let activity = self.activity(topic)?;
        let entry = self.entry::<T>(topic, TopicKind::Latest, None, || {
            let slot = Arc::new(LatestSlot::<T> {
                message: Mutex::new(None),
                activity: activity.clone(),
                tap: OnceLock::new(),
                read_seq: AtomicU64::new(0),
            });
            (slot.clone(), slot)
        })?;
        downcast(entry)
    }

    fn queue_slot<T: Send + 'static>(
        &self,
        topic: &str,
        spec: QueueSpec,
    ) -> Result<Arc<QueueSlot<T>>, BusError> {
        if spec.capacity == 0 {
            return Err(BusError::ZeroCapacity {
                topic: topic.to_string(),
            });
        }
        let activity = self.activity(topic)?;
        let entry = self.entry::<T>(topic, TopicKind::Queue, Some(spec), || {
            let slot = Arc::new(QueueSlot::<T> {
                spec,
                messages: Mutex::new(VecDeque::with_capacity(spec.capacity)),
                activity: activity.clone(),
                dropped: AtomicU64::new(0),
                rejected: AtomicU64::new(0),
                receiver_taken: AtomicBool::new(false),
            });
            (slot.clone(), slot)
        })?;
        downcast(entry)
    }

    /// The topic's slot, created by `make` if the topic is new, after checking type and kind.
    fn entry<T: 'static>(
        &self,
        topic: &str,
        kind: TopicKind,
        queue_spec: Option<QueueSpec>,
        make: impl FnOnce() -> (Arc<dyn Any + Send + Sync>, Arc<dyn TopicCounters>),
    ) -> Result<Arc<dyn Any + Send + Sync>, BusError> {
        if topic.is_empty() {
            return Err(BusError::EmptyTopicName);
        }
        let mut topics = lock(&self.topics);
        if let Some(entry) = topics.get(topic) {
            if entry.type_id != TypeId::of::<T>() {
                return Err(BusError::TypeMismatch {
                    topic: topic.to_string(),
                    existing: entry.type_name,
                    requested: type_name::<T>(),
                });
            }
            if entry.kind != kind {
                return Err(BusError::KindMismatch {
                    topic: topic.to_string(),
                    existing: entry.kind,
                    requested: kind,
                });
            }
            if let (Some(existing), Some(requested)) = (entry.queue_spec, queue_spec) {
                if existing != requested {
                    return Err(BusError::QueueSpecMismatch {
                        topic: topic.to_string(),
                        existing,
                        requested,
                    });
                }
            }
            return Ok(entry.slot.clone());
        }
        let (slot, counters) = make();
        topics.insert(
            topic.to_string(),
            TopicEntry {
                type_id: TypeId::of::<T>(),
                type_name: type_name::<T>(),
                kind,
                queue_spec,
                slot: slot.clone(),
                counters,
            },
        );
        Ok(slot)
    }
}

fn downcast<S: Send + Sync + 'static>(
    slot: Arc<dyn Any + Send + Sync>,
) -> Result<Arc<S>, BusError> {
    // The entry's TypeId was checked against T, so the slot is a S; a failure here would be a bug
    // in this module, reported as a type mismatch rather than a panic.
    slot.downcast::<S>().map_err(|_| BusError::TypeMismatch {
        topic: String::new(),
        existing: "another slot type",
        requested: type_name::<S>(),
    })
}

/// What a tapped topic hands each message to.
pub type Tap<T> = Box<dyn Fn(&Arc<Message<T>>) + Send + Sync>;

struct LatestSlot<T> {
    message: Mutex<Option<Arc<Message<T>>>>,
    activity: Arc<TopicActivity>,
    tap: OnceLock<Tap<T>>,
    /// The newest sequence number any subscriber has read (set under `message`'s lock, so a
    /// publisher replacing a message knows whether it was read).
    read_seq: AtomicU64,
}

impl<T> LatestSlot<T> {
    /// The current message, noted as read.
    fn read(&self) -> Option<Arc<Message<T>>> {
        let slot = lock(&self.message);
        let message = slot.clone()?;
        self.read_seq.fetch_max(message.seq, Ordering::AcqRel);
        Some(message)
    }

    /// Whether a subscriber read `message` (the slot's lock held).
    fn was_read(&self, message: &Message<T>) -> bool {
        self.read_seq.load(Ordering::Acquire) >= message.seq
    }
}

impl<T: Send + Sync> TopicCounters for LatestSlot<T> {
    fn counters(&self) -> (u64, u64, u64, usize) {
        (self.activity.published(), 0, 0, 0)
    }
}

/// Writes a latest-value topic. Cloneable: several tasks may publish on one topic.
pub struct Publisher<T> {
    slot: Arc<LatestSlot<T>>,
}

impl<T> Clone for Publisher<T> {
    fn clone(&self) -> Self {
        Publisher {
            slot: self.slot.clone(),
        }
    }
}

impl<T> fmt::Debug for Publisher<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Publisher")
            .field("type", &type_name::<T>())
            .finish()
    }
}

impl<T> Publisher<T> {
    /// Replaces the topic's value; returns the message's sequence number.
    pub fn publish(&self, stamp: Timestamp, value: T) -> u64 {
        self.publish_noting_read(stamp, value).0
    }

    /// Publishes like [`Publisher::publish`], and says whether any subscriber read the message
    /// it replaced (`None`: the topic had none). Once replaced a message cannot be read, so
    /// the answer is final.
    pub fn publish_noting_read(&self, stamp: Timestamp, value: T) -> (u64, Option<bool>) {
        let mut slot = lock(&self.slot.message);
        // Numbered under the lock so the slot's sequence numbers only grow.
        let seq = self.slot.activity.count();
        let message = Arc::new(Message { stamp, seq, value });
        if let Some(tap) = self.slot.tap.get() {
            tap(&message);
        }
        let replaced_read = slot.as_ref().map(|old| self.slot.was_read(old));
        *slot = Some(message);
        drop(slot);
        self.slot.activity.wake();
        (seq, replaced_read)
    }

    /// Whether any subscriber has read the topic's current message (`None`: it has none).
    pub fn current_read(&self) -> Option<bool> {
        let slot = lock(&self.slot.message);
        slot.as_ref().map(|message| self.slot.was_read(message))
    }
}

/// Reads a latest-value topic, remembering what it has seen.
pub struct Subscriber<T> {
    slot: Arc<LatestSlot<T>>,
    seen_seq: u64,
}

impl<T> fmt::Debug for Subscriber<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Subscriber")
            .field("type", &type_name::<T>())
            .field("seen_seq", &self.seen_seq)
            .finish()
    }
}

impl<T> Subscriber<T> {
    /// Whether a message newer than the last one this subscriber read is on the topic.
    pub fn updated(&self) -> bool {
        self.slot.activity.published() > self.seen_seq
    }

    /// The newest message, new or not, marking it seen.
    pub fn latest(&mut self) -> Option<Arc<Message<T>>> {
        let message = self.slot.read()?;
        self.seen_seq = message.seq;
        Some(message)
    }

    /// The newest message only if it is new since the last read, marking it seen.
    pub fn take_new(&mut self) -> Option<Arc<Message<T>>> {
        // Checked first so a message this subscriber has seen is not read again; checked
        // again because the count moves just before the message is replaced.
        if !self.updated() {
            return None;
        }
        let message = self.slot.read()?;
        if message.seq <= self.seen_seq {
            return None;
        }
        self.seen_seq = message.seq;
        Some(message)
    }

    /// The newest message without marking it seen (by this subscriber: the topic counts it
    /// read).
    pub fn peek(&self) -> Option<Arc<Message<T>>> {
        self.slot.read()
    }

    /// Sequence number of the last message read (0 before the first).
    pub fn seen_seq(&self) -> u64 {
        self.seen_seq
    }
}

struct QueueSlot<T> {
    spec: QueueSpec,
    messages: Mutex<VecDeque<Message<T>>>,
    activity: Arc<TopicActivity>,
    dropped: AtomicU64,
    rejected: AtomicU64,
    receiver_taken: AtomicBool,
}

impl<T: Send> TopicCounters for QueueSlot<T> {
    fn counters(&self) -> (u64, u64, u64, usize) {
        (
            self.activity.published(),
            self.dropped.load(Ordering::Acquire),
            self.rejected.load(Ordering::Acquire),
            lock(&self.messages).len(),
        )
    }
}

/// Sends into a queue topic. Cloneable: several tasks may send.
pub struct QueueSender<T> {
    queue: Arc<QueueSlot<T>>,
}

impl<T> Clone for QueueSender<T> {
    fn clone(&self) -> Self {
        QueueSender {
            queue: self.queue.clone(),
        }
    }
}

impl<T> fmt::Debug for QueueSender<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("QueueSender")
            .field("type", &type_name::<T>())
            .field("spec", &self.queue.spec)
            .finish()
    }
}

impl<T> QueueSender<T> {
    /// Queues `value` stamped `stamp`, applying the overflow policy when full.
    pub fn send(&self, stamp: Timestamp, value: T) -> Result<Sent, QueueFull<T>> {
        let mut messages = lock(&self.queue.messages);
        let seq = self.queue.activity.count();
        let mut sent = Sent::Queued;
        if messages.len() >= self.queue.spec.capacity {
            match self.queue.spec.overflow {
                Overflow::Reject => {
                    self.queue.rejected.fetch_add(1, Ordering::AcqRel);
                    return Err(QueueFull(value));
                }
                Overflow::DropOldest => {
                    messages.pop_front();
                    self.queue.dropped.fetch_add(1, Ordering::AcqRel);
                    sent = Sent::DroppedOldest;
                }
            }
        }
        messages.push_back(Message { stamp, seq, value });
        drop(messages);
        self.queue.activity.wake();
        Ok(sent)
    }

    pub fn dropped(&self) -> u64 {
        self.queue.dropped.load(Ordering::Acquire)
    }

    pub fn rejected(&self) -> u64 {
        self.queue.rejected.load(Ordering::Acquire)
    }
}

/// The one receiver of a queue topic.
pub struct QueueReceiver<T> {
    queue: Arc<QueueSlot<T>>,
}

impl<T> fmt::Debug for QueueReceiver<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("QueueReceiver")
            .field("type", &type_name::<T>())
            .field("spec", &self.queue.spec)
            .finish()
    }
}

impl<T> QueueReceiver<T> {
    /// The oldest waiting message.
    pub fn recv(&mut self) -> Option<Message<T>> {
        lock(&self.queue.messages).pop_front()
    }

    /// Every waiting message, oldest first.
    pub fn drain(&mut self) -> Vec<Message<T>> {
        lock(&self.queue.messages).drain(..).collect()
    }

    pub fn len(&self) -> usize {
        lock(&self.queue.messages).len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Messages lost to [`Overflow::DropOldest`] so far.
    pub fn dropped(&self) -> u64 {
        self.queue.dropped.load(Ordering::Acquire)
    }

    /// Messages refused by [`Overflow::Reject`] so far.
    pub fn rejected(&self) -> u64 {
        self.queue.rejected.load(Ordering::Acquire)
    }
}

impl<T> Drop for QueueReceiver<T> {
    fn drop(&mut self) {
        self.queue.receiver_taken.store(false, Ordering::Release);
    }
}

#[cfg(test)]
mod tests;
