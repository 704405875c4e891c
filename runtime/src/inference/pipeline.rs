//! One step of work on a thread of its own: a task hands over a job at one step and collects
//! its result at the next, so the step returns at once instead of waiting for an inference.
//! At most one job is in flight; collecting waits for it, so what a task publishes does not
//! depend on how fast the thread was (a lockstep simulation stays deterministic).

use std::sync::mpsc::{channel, Receiver, Sender};
use std::thread::JoinHandle;

/// The thread ended (its work panicked) with a job in flight.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("the inference thread {0} ended")]
pub struct PipelineGone(pub String);

pub struct Pipeline<J, R> {
    name: String,
    jobs: Option<Sender<J>>,
    results: Receiver<R>,
    thread: Option<JoinHandle<()>>,
    in_flight: bool,
}

impl<J: Send + 'static, R: Send + 'static> Pipeline<J, R> {
    /// A thread named `name` that runs `work` on each job handed to it.
    pub fn spawn(
        name: &str,
        mut work: impl FnMut(J) -> R + Send + 'static,
    ) -> std::io::Result<Self> {
        let (jobs, job_queue) = channel::<J>();
        let (result_sender, results) = channel::<R>();
        let thread = std::thread::Builder::new()
            .name(name.to_string())
            .spawn(move || {
                for job in job_queue {
                    if result_sender.send(work(job)).is_err() {
                        break;
                    }
                }
            })?;
        Ok(Self {
            name: name.to_string(),
            jobs: Some(jobs),
            results,
            thread: Some(thread),
            in_flight: false,
        })
    }

    /// Whether a job was handed over and its result not yet collected.
    pub fn in_flight(&self) -> bool {
        self.in_flight
    }

    /// Hands `job` over, first collecting the one in flight (returned).
    pub fn submit(&mut self, job: J) -> Result<Option<R>, PipelineGone> {
        let previous = self.collect()?;
        let gone = || PipelineGone(self.name.clone());
        self.jobs
            .as_ref()
            .ok_or_else(gone)?
            .send(job)
            .map_err(|_| gone())?;
        self.in_flight = true;
        Ok(previous)
    }

    /// The result of the job in flight, waiting for it; `None` when none is.
    pub fn collect(&mut self) -> Result<Option<R>, PipelineGone> {
        if !self.in_flight {
            return Ok(None);
        }
        self.in_flight = false;
        self.results
            .recv()
            .map(Some)
            .map_err(|_| PipelineGone(self.name.clone()))
    }
}

impl<J, R> Drop for Pipeline<J, R> {
    fn drop(&mut self) {
        // Closing the queue ends the thread once its job is done.
        self.jobs = None;
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_result_comes_back_at_the_next_hand_over_in_order() {
        let mut pipeline = Pipeline::spawn("square", |x: u64| x * x).unwrap();
        assert_eq!(pipeline.collect().unwrap(), None);
        assert_eq!(pipeline.submit(3).unwrap(), None);
        assert!(pipeline.in_flight());
        assert_eq!(pipeline.submit(4).unwrap(), Some(9));
        assert_eq!(pipeline.collect().unwrap(), Some(16));
        assert!(!pipeline.in_flight());
        assert_eq!(pipeline.collect().unwrap(), None);
    }

    #[test]
    fn a_thread_that_died_is_a_named_error_not_a_hang() {
        let mut pipeline = Pipeline::spawn("fragile", |x: u64| {
            assert!(x < 10, "a job the work cannot do");
            x
        })
        .unwrap();
        assert_eq!(pipeline.submit(1).unwrap(), None);
        assert_eq!(pipeline.submit(99).unwrap(), Some(1));
        let error = pipeline.collect().unwrap_err();
        assert!(error.to_string().contains("fragile"), "{error}");
    }
}
