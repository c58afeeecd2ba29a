//! A buffer mapping (or the GPU finishing its work) as a future: wgpu reports both through callbacks, which on
//! native run inside `Device::poll` and in a browser only once control returns to its event loop. So a wait is:
//! poll (blocks on native until the work is done; a no-op in a browser), then await the callback's outcome
//! (ready at once on native; woken by the callback in a browser). One code path serves both targets.

use std::future::poll_fn;
use std::sync::{Arc, Mutex};
use std::task::{Poll, Waker};

/// The outcome of a callback wgpu calls once: pending, or whether it succeeded.
#[derive(Clone, Default)]
pub(crate) struct Mapping(Arc<Mutex<State>>);

#[derive(Default)]
struct State {
    outcome: Option<bool>,
    waker: Option<Waker>,
}

impl Mapping {
    /// A mapping that has already succeeded (a buffer mapped at creation).
    pub(crate) fn mapped() -> Mapping {
        let mapping = Mapping::default();
        mapping.settle(true);
        mapping
    }

    /// Maps `slice` in `mode`; the mapping's outcome arrives with wgpu's callback.
    pub(crate) fn request(slice: &wgpu::BufferSlice<'_>, mode: wgpu::MapMode) -> Mapping {
        let mapping = Mapping::default();
        let settle = mapping.clone();
        slice.map_async(mode, move |result| settle.settle(result.is_ok()));
        mapping
    }

    /// Settles once `queue` has finished the work submitted to it so far.
    pub(crate) fn work_done(queue: &wgpu::Queue) -> Mapping {
        let mapping = Mapping::default();
        let settle = mapping.clone();
        queue.on_submitted_work_done(move || settle.settle(true));
        mapping
    }

    fn settle(&self, ok: bool) {
        let mut state = self.0.lock().expect("mapping poisoned");
        state.outcome = Some(ok);
        if let Some(waker) = state.waker.take() {
            waker.wake();
        }
    }

    /// Whether the callback has come (and then whether it succeeded), without waiting.
    pub(crate) fn outcome(&self) -> Option<bool> {
        self.0.lock().expect("mapping poisoned").outcome
    }

    /// The outcome, once the callback has come.
    pub(crate) async fn settled(&self) -> bool {
        poll_fn(|cx| {
            let mut state = self.0.lock().expect("mapping poisoned");
            match state.outcome {
                Some(ok) => Poll::Ready(ok),
                None => {
                    state.waker = Some(cx.waker().clone());
                    Poll::Pending
                }
            }
        })
        .await
    }
}
