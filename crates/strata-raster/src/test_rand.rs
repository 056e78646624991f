//! A tiny xorshift generator for the crate's unit tests, so that their random cases are the same
//! on every run and every machine.

/// Xorshift64 state; seed it with any non-zero value.
pub(crate) struct Rand(pub(crate) u64);

impl Rand {
    /// The next 64 random bits.
    pub(crate) fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// A number below `n`.
    pub(crate) fn below(&mut self, n: u32) -> i32 {
        ((self.next() >> 33) % u64::from(n)) as i32
    }

    /// A number in `[0, 1)`, a multiple of 2^-24.
    pub(crate) fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
}
