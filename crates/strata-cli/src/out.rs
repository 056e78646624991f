//! Writing to stdout without panicking when the reader goes away (`strata methods | head`).
//!
//! `println!` panics on a closed pipe. These macros return the `io::Error` instead, the commands
//! pass it up with `?`, and `main` ends quietly and successfully on a broken pipe, as ripgrep does.

/// `println!` to stdout that returns `io::Result<()>`.
macro_rules! outln {
    () => {{
        use std::io::Write as _;
        writeln!(std::io::stdout().lock())
    }};
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        writeln!(std::io::stdout().lock(), $($arg)*)
    }};
}

/// `print!` to stdout that returns `io::Result<()>`.
macro_rules! out {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        write!(std::io::stdout().lock(), $($arg)*)
    }};
}

/// True if `e` (or a cause of it) is a broken pipe: the reader of our output has gone.
pub(crate) fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}
