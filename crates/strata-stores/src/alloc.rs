//! Block allocation from a shared counter: how the pool-based stores (the linked list's nodes,
//! TFSS's sections) hand out pool entries without an atomic per entry.
//!
//! On the GPU every allocation is an `atomicAdd` on the pool counter (Jähne 2014 §2.2; Tsopouridis 2021
//! Alg. 5). Here each rasterizer strip is scanned by one thread, so a strip reserves a block of
//! entries with one `fetch_add` and hands them out one by one with plain arithmetic: the counter is
//! touched once per block. A block is written only by the thread that reserved it, and the end of
//! the parallel pass is the synchronisation point before anything reads the pool.
//!
//! When the counter passes the capacity the pool is exhausted: [`BlockCursor::next`] returns
//! `None` and the caller drops (and counts) what it could not store. A strip may hold up to
//! `block - 1` reserved but unused entries when it ends.

use std::sync::atomic::{AtomicU32, Ordering::Relaxed};

/// One strip's current block of reserved pool entries.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct BlockCursor {
    cur: u32,
    end: u32,
    exhausted: bool,
}

impl BlockCursor {
    /// The next free entry of a pool of `capacity` entries whose allocation counter is `counter`,
    /// reserving `block` more when the current block is used up; `None` once the pool is full.
    #[inline(always)]
    pub(crate) fn next(&mut self, counter: &AtomicU32, capacity: u32, block: u32) -> Option<u32> {
        if self.cur == self.end && !self.refill(counter, capacity, block) {
            return None;
        }
        let index = self.cur;
        self.cur += 1;
        Some(index)
    }

    /// Reserves the next block; false once the pool is exhausted.
    #[cold]
    fn refill(&mut self, counter: &AtomicU32, capacity: u32, block: u32) -> bool {
        if self.exhausted {
            return false;
        }
        let start = counter.fetch_add(block, Relaxed);
        if start >= capacity {
            self.exhausted = true;
            return false;
        }
        self.cur = start;
        self.end = start.saturating_add(block).min(capacity);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_are_disjoint_and_stop_at_capacity() {
        let counter = AtomicU32::new(0);
        let (mut a, mut b) = (BlockCursor::default(), BlockCursor::default());
        let mut got = Vec::new();
        for _ in 0..3 {
            got.push(a.next(&counter, 10, 4));
            got.push(b.next(&counter, 10, 4));
        }
        // a reserves 0..4, b 4..8.
        assert_eq!(got, [Some(0), Some(4), Some(1), Some(5), Some(2), Some(6)]);
        assert_eq!(a.next(&counter, 10, 4), Some(3));
        assert_eq!(a.next(&counter, 10, 4), Some(8)); // 8..10, cut at the capacity
        assert_eq!(a.next(&counter, 10, 4), Some(9));
        assert_eq!(a.next(&counter, 10, 4), None);
        assert_eq!(b.next(&counter, 10, 4), Some(7));
        assert_eq!(b.next(&counter, 10, 4), None);
        assert_eq!(b.next(&counter, 10, 4), None, "stays exhausted");
    }
}
