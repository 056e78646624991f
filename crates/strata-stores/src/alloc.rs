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
//! `block - 1` reserved but unused entries when it ends; [`block_size`] keeps all strips' tails
//! within a sixteenth of the pool, or `strips × 63` for a small one, and [`capacity_for`] sizes a
//! pool with room for them.

use std::sync::atomic::{AtomicU32, Ordering::Relaxed};

/// The most entries a strip reserves at a time.
///
/// Two threads reserving blocks in turn write the pool in interleaved blocks. With blocks of
/// 64 entries the linked list's scan of the full dragon was only 1.5 times as fast on two
/// threads as on one, not twice; with blocks of 1,024 the two-thread scan took 17 % less time
/// (AMD EPYC, 2 cores): the cores' writes meet at a block boundary sixteen times less often,
/// and each meeting costs cache lines moving between the cores (the prefetchers run ahead into
/// the neighbouring block).
pub(crate) const MAX_BLOCK: u32 = 1024;

/// The fewest entries a strip reserves at a time, for a pool too small for [`MAX_BLOCK`]s.
pub(crate) const MIN_BLOCK: u32 = 64;

/// The fewest entries a pool needs so that `need` of them can be handed out whatever the strips
/// leave unused at the ends of their last blocks. Those tails are at most `strips × (block − 1)`:
/// with [`MIN_BLOCK`]s, below `strips × 64`; with larger blocks, [`block_size`] makes a block at
/// most a `16 · strips`-th of the pool, so below a sixteenth of it.
pub(crate) fn capacity_for(need: u64, strips: usize) -> u64 {
    let strips = strips.max(1) as u64;
    (need + strips * u64::from(MIN_BLOCK)).max(need * 16 / 15 + 1)
}

// TFSS's packed sections need blocks of whole 64-bit words: multiples of 64 sections.
const _: () = assert!(MIN_BLOCK.is_multiple_of(64) && MAX_BLOCK.is_multiple_of(64));

/// Entries a strip reserves at a time from a pool of `capacity` entries cut into `strips`
/// strips: at most a `16 · strips`-th of the pool, so that the blocks all strips hold unused
/// when they end stay within a sixteenth of it; at most [`MAX_BLOCK`], at least [`MIN_BLOCK`],
/// and a multiple of it (TFSS's packed words need blocks of a multiple of 64 sections).
pub(crate) fn block_size(capacity: usize, strips: usize) -> u32 {
    let share = capacity / (16 * strips.max(1));
    let share = share.clamp(MIN_BLOCK as usize, MAX_BLOCK as usize) as u32;
    share - share % MIN_BLOCK
}

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

    /// The entries left in the current block, `cur..end`, for a caller that steps through them
    /// in registers ([`BlockCursor::set_bounds`] gives them back).
    #[inline(always)]
    pub(crate) fn bounds(&self) -> (u32, u32) {
        (self.cur, self.end)
    }

    /// Sets what [`BlockCursor::bounds`] gave, advanced.
    #[inline(always)]
    pub(crate) fn set_bounds(&mut self, cur: u32, end: u32) {
        (self.cur, self.end) = (cur, end);
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

    /// Blocks are as large as allowed for a frame's pool, smaller for a small pool, so that the
    /// strips' unused block tails stay within a sixteenth of it; always a multiple of 64.
    #[test]
    fn block_size_shrinks_with_the_pool() {
        // The linked list's default pool of a 1280x720 frame (twice the pixels), 45 strips.
        assert_eq!(block_size(2 * 1280 * 720, 45), MAX_BLOCK);
        assert_eq!(block_size(16 * 45 * 300, 45), 256);
        assert_eq!(block_size(1000, 45), MIN_BLOCK);
        assert_eq!(block_size(0, 0), MIN_BLOCK);
        for (capacity, strips) in [(100_000, 45), (1 << 20, 3), (5000, 1), (16 * 45 * 700, 45)] {
            let b = block_size(capacity, strips);
            assert_eq!(b % 64, 0, "{capacity} {strips}");
            let b = b as usize;
            assert!(b == MIN_BLOCK as usize || strips * b <= capacity / 16);
        }
    }

    /// A pool of `capacity_for(need, strips)` entries hands out `need` entries even when every
    /// strip leaves its last block all but unused.
    #[test]
    fn capacity_for_leaves_room_for_the_block_tails() {
        for strips in [1usize, 3, 45, 720, 8192] {
            for need in [0u64, 1, 100, 10_000, 945_834, 5_000_000, 1 << 30] {
                let n = capacity_for(need, strips);
                let b = u64::from(block_size(n as usize, strips));
                let tails = strips as u64 * (b - 1);
                assert!(
                    n >= need + tails,
                    "need {need}, {strips} strips: {n} < {need} + {tails}"
                );
                // And not much more than that: a sixteenth, or a block a strip.
                assert!(n <= (need + strips as u64 * 64).max(need * 16 / 15 + 1));
            }
        }
    }

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
