//! A topic's activity: how many messages it has had, and which threads to wake when it gets
//! one. What an input-triggered task waits on, whatever the topic's message type.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard, PoisonError};
use std::thread::{Thread, ThreadId};

/// One topic's message count and waiters. Shared by the topic's slot (which counts) and by the
/// tasks triggered by it (which read the count and ask to be woken).
#[derive(Debug, Default)]
pub struct TopicActivity {
    published: AtomicU64,
    waiters: Mutex<Vec<Thread>>,
}

fn lock(waiters: &Mutex<Vec<Thread>>) -> MutexGuard<'_, Vec<Thread>> {
    // A list of thread handles is consistent whatever panicked while it was held.
    waiters.lock().unwrap_or_else(PoisonError::into_inner)
}

impl TopicActivity {
    /// Messages offered to the topic so far (the last one's sequence number).
    pub fn published(&self) -> u64 {
        self.published.load(Ordering::Acquire)
    }

    /// Counts one more message; returns its sequence number. The caller wakes the waiters
    /// with [`TopicActivity::wake`] once the message can be read.
    pub(super) fn count(&self) -> u64 {
        self.published.fetch_add(1, Ordering::AcqRel) + 1
    }

    /// Unparks every waiting thread. A thread unparked before it parks returns from its next
    /// `park` at once, so a message between a waiter's check and its park is never missed.
    pub(super) fn wake(&self) {
        for thread in lock(&self.waiters).iter() {
            thread.unpark();
        }
    }

    /// Unpark `thread` whenever a message is published, until [`TopicActivity::unwatch`].
    pub fn watch(&self, thread: Thread) {
        let mut waiters = lock(&self.waiters);
        if !waiters.iter().any(|t| t.id() == thread.id()) {
            waiters.push(thread);
        }
    }

    pub fn unwatch(&self, thread: ThreadId) {
        lock(&self.waiters).retain(|t| t.id() != thread);
    }
}
