//! Renders waiting for the render threads (`serve.rs`): at most one per client (its newest camera: an older one still
//! waiting is answered 409 and dropped, not rendered), a queue bounded in renders and in pixels, and frame
//! rates bounded per client.

use std::collections::{HashMap, VecDeque};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use crate::http::HttpError;
use crate::query::RenderQuery;

/// The most renders waiting at once (all clients together); more are answered 503.
pub const MAX_QUEUED: usize = 64;
/// The most pixels waiting to be rendered (four of the largest renders): large renders cannot pile up work
/// that would keep every other client waiting for minutes.
pub const MAX_QUEUED_PIXELS: usize = 4 * crate::catalog::MAX_PIXELS;

/// A finished render and how long the engine took.
pub struct Frame {
    pub rendered: raypatch::Rendered,
    pub render_time: Duration,
}

pub type Reply = Result<Frame, HttpError>;

pub struct Job {
    pub query: RenderQuery,
    pub reply: Sender<Reply>,
}

#[derive(Default)]
pub struct RenderQueue {
    state: Mutex<QueueState>,
    wake: Condvar,
}

#[derive(Default)]
struct QueueState {
    jobs: VecDeque<Job>,
    /// The pixels of the jobs waiting.
    pixels: usize,
    stopped: bool,
}

fn pixels(job: &Job) -> usize {
    job.query.width * job.query.height
}

/// A lock that a panic elsewhere does not make unusable: the state it guards is valid after any one update.
fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

impl RenderQueue {
    /// Queues a render; the receiver gets its frame or why there is none.
    pub fn submit(&self, query: RenderQuery) -> Result<Receiver<Reply>, HttpError> {
        let mut state = lock(&self.state);
        if state.stopped {
            return Err(HttpError::new(503, "server: stopping"));
        }
        if let Some(client) = &query.client {
            if let Some(i) = state.jobs.iter().position(|j| j.query.client.as_ref() == Some(client)) {
                if let Some(stale) = state.jobs.remove(i) {
                    state.pixels -= pixels(&stale);
                    let _ =
                        stale.reply.send(Err(HttpError::new(409, "render: replaced by a newer camera of this client")));
                }
            }
        }
        let (reply, frame) = channel();
        let job = Job { query, reply };
        if state.jobs.len() >= MAX_QUEUED || state.pixels + pixels(&job) > MAX_QUEUED_PIXELS {
            return Err(HttpError::new(
                503,
                format!("server: busy ({} renders of {} pixels waiting); try again", state.jobs.len(), state.pixels),
            ));
        }
        state.pixels += pixels(&job);
        state.jobs.push_back(job);
        self.wake.notify_one();
        Ok(frame)
    }

    /// The oldest waiting render; `None` once stopped.
    pub fn next(&self) -> Option<Job> {
        let mut state = lock(&self.state);
        loop {
            if state.stopped {
                return None;
            }
            if let Some(job) = state.jobs.pop_front() {
                state.pixels -= pixels(&job);
                return Some(job);
            }
            state = self.wake.wait(state).unwrap_or_else(|poisoned| poisoned.into_inner());
        }
    }

    /// Stops the queue: waiting renders are answered 503, `next` returns `None`.
    pub fn stop(&self) {
        let mut state = lock(&self.state);
        state.stopped = true;
        state.pixels = 0;
        for job in state.jobs.drain(..) {
            let _ = job.reply.send(Err(HttpError::new(503, "server: stopping")));
        }
        self.wake.notify_all();
    }
}

/// Token buckets, one per key (a client id or an address): `per_second` renders a second, in bursts of at most
/// as many. Buckets that have refilled are forgotten when the table is full, so it never holds more than
/// `max_keys`.
pub struct RateLimiter {
    buckets: Mutex<HashMap<String, Bucket>>,
    per_second: f64,
    max_keys: usize,
    what: &'static str,
}

struct Bucket {
    tokens: f64,
    updated: Instant,
}

impl RateLimiter {
    pub fn new(per_second: u32, max_keys: usize, what: &'static str) -> RateLimiter {
        RateLimiter { buckets: Mutex::new(HashMap::new()), per_second: per_second.into(), max_keys, what }
    }

    /// Takes one render from `key`'s bucket: 429 when it is empty, 503 when too many keys are active.
    pub fn take(&self, key: &str) -> Result<(), HttpError> {
        let now = Instant::now();
        let mut buckets = lock(&self.buckets);
        let full = self.per_second;
        let refill = |b: &mut Bucket| {
            b.tokens = (b.tokens + now.duration_since(b.updated).as_secs_f64() * full).min(full);
            b.updated = now;
        };
        if !buckets.contains_key(key) && buckets.len() >= self.max_keys {
            buckets.retain(|_, b| {
                refill(b);
                b.tokens < full
            });
            if buckets.len() >= self.max_keys {
                return Err(HttpError::new(
                    503,
                    format!("server: over {} active {}s; try again", self.max_keys, self.what),
                ));
            }
        }
        let bucket = buckets.entry(key.to_string()).or_insert(Bucket { tokens: full, updated: now });
        refill(bucket);
        if bucket.tokens < 1.0 {
            return Err(HttpError::new(
                429,
                format!("render: over {} frames per second from this {}", self.per_second, self.what),
            ));
        }
        bucket.tokens -= 1.0;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::catalog::ViewOutput;

    fn query(client: Option<&str>) -> RenderQuery {
        sized(client, 8)
    }

    fn sized(client: Option<&str>, side: usize) -> RenderQuery {
        RenderQuery {
            model: 0,
            scene: 0,
            output: ViewOutput::Rgb,
            width: side,
            height: side,
            pose: glam::DMat4::IDENTITY,
            client: client.map(String::from),
        }
    }

    #[test]
    fn a_clients_newer_camera_replaces_its_waiting_one() {
        let queue = RenderQueue::default();
        let first = queue.submit(query(Some("a"))).unwrap();
        let other = queue.submit(query(Some("b"))).unwrap();
        let newest = queue.submit(query(Some("a"))).unwrap();
        assert_eq!(first.recv().unwrap().err().unwrap().status, 409);
        assert_eq!(queue.next().unwrap().query.client.as_deref(), Some("b"));
        assert_eq!(queue.next().unwrap().query.client.as_deref(), Some("a"));
        // Requests without a client id are each answered.
        let anonymous: Vec<_> = (0..3).map(|_| queue.submit(query(None)).unwrap()).collect();
        for _ in 0..MAX_QUEUED - 3 {
            queue.submit(query(None)).unwrap();
        }
        assert_eq!(queue.submit(query(None)).unwrap_err().status, 503);
        queue.stop();
        assert!(queue.next().is_none());
        assert_eq!(anonymous[0].recv().unwrap().err().unwrap().status, 503);
        drop((other, newest));
    }

    #[test]
    fn the_pixels_waiting_are_bounded() {
        let queue = RenderQueue::default();
        let big: Vec<_> = (0..4).map(|_| queue.submit(sized(None, 512)).unwrap()).collect();
        assert_eq!(queue.submit(sized(None, 4)).unwrap_err().status, 503);
        // Renders taken and a client's replaced camera no longer count.
        queue.next().unwrap();
        let replaced = queue.submit(sized(Some("b"), 4)).unwrap();
        queue.submit(sized(Some("b"), 4)).unwrap();
        assert_eq!(replaced.recv().unwrap().err().unwrap().status, 409);
        assert_eq!(lock(&queue.state).pixels, 3 * 512 * 512 + 16);
        assert_eq!(queue.submit(sized(None, 512)).unwrap_err().status, 503);
        drop(big);
    }

    #[test]
    fn buckets_bound_rates_and_keys() {
        let limiter = RateLimiter::new(5, 2, "client");
        for _ in 0..5 {
            limiter.take("a").unwrap();
        }
        assert_eq!(limiter.take("a").unwrap_err().status, 429);
        limiter.take("b").unwrap();
        // "a" and "b" are both below full: a third key is refused rather than growing the table.
        assert_eq!(limiter.take("c").unwrap_err().status, 503);
        std::thread::sleep(Duration::from_millis(1100));
        limiter.take("c").unwrap();
        assert!(lock(&limiter.buckets).len() <= 2);
    }
}
