//! The field's reader-writer lock, and the rule that keeps it free of deadlock: a thread that
//! holds a distribution re-enters past a waiting writer (see the crate documentation).

use parking_lot::RwLock;
use sdguide::GuidingField;
use std::cell::Cell;

thread_local! {
    /// Live distributions this thread made: while any is held, its shared calls re-enter.
    pub(crate) static HELD: Cell<u32> = const { Cell::new(0) };
}

/// Whether this thread's shared acquisitions re-enter past a waiting writer: it holds a
/// distribution, which the writer waits for (see the crate documentation).
pub(crate) fn reentrant() -> bool {
    HELD.with(Cell::get) > 0
}

/// Shared access for one call: behind a waiting writer (fair), unless [`reentrant`].
pub(crate) fn shared(
    lock: &RwLock<GuidingField>,
) -> parking_lot::RwLockReadGuard<'_, GuidingField> {
    if reentrant() {
        lock.read_recursive()
    } else {
        lock.read()
    }
}
