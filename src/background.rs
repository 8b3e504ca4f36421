//! Cooperative pause points for background work.
//!
//! The daemon's watchers (its dashboard's images) are made by background threads that must
//! never take from a frame in flight (issue 19). Operating-system priorities do not ensure
//! that on a small machine: on the 2-core bench a `SCHED_IDLE` thread still ran in the frame
//! thread's serial stages and slowed the frames by about 10 %. So long background jobs are
//! cut into slices: the loops they run (the simulated camera's exposure, PNG encoding, the
//! viewing scale) call [`checkpoint`] between slices of about a millisecond, and a thread
//! that works for the watchers installs a hook ([`install`]) that waits there while a frame
//! is in flight.
//!
//! On every other thread (the frame thread, its render pool, the CLI) no hook is installed
//! and [`checkpoint`] is one thread-local read.

use std::cell::RefCell;
use std::sync::Arc;

/// What a background thread does at a pause point (waits while a frame is in flight).
pub type Hook = Arc<dyn Fn() + Send + Sync>;

thread_local! {
    static HOOK: RefCell<Option<Hook>> = const { RefCell::new(None) };
}

/// Makes `hook` the calling thread's pause: [`checkpoint`]s on this thread call it.
pub fn install(hook: Hook) {
    HOOK.with(|h| *h.borrow_mut() = Some(hook));
}

/// A point between slices of work where a background thread may pause; nothing on the
/// frame's own threads.
#[inline]
pub fn checkpoint() {
    // Clone out of the cell first: the hook may run long and must not hold the borrow.
    let hook = HOOK.with(|h| h.borrow().clone());
    if let Some(h) = hook {
        h();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    #[test]
    fn a_hook_runs_only_on_the_thread_that_installed_it() {
        let calls = Arc::new(AtomicUsize::new(0));
        let c = calls.clone();
        std::thread::spawn(move || {
            install(Arc::new(move || {
                c.fetch_add(1, Ordering::Relaxed);
            }));
            checkpoint();
            checkpoint();
        })
        .join()
        .unwrap();
        checkpoint();
        assert_eq!(calls.load(Ordering::Relaxed), 2);
    }
}
