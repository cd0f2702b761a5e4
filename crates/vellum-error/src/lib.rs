#![warn(missing_docs)]
//! The one error type of vellum's crates. Every variant names what failed, so a message that reaches the
//! user says which object, pass or file was involved and what was expected.

use std::path::PathBuf;

/// Everything that can fail in vellum. Bad user input becomes a variant with a sentence saying what
/// was expected; broken internal invariants are bugs and panic instead.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A Vulkan call returned an error.
    #[error("Vulkan call failed while {what}: {result}")]
    Vulkan {
        /// The object or pass, as "creating the sampler".
        what: String,
        /// The `VkResult`'s name (this crate names no Vulkan type, so the layers without Vulkan
        /// use it).
        result: String,
    },

    /// The Vulkan loader library could not be opened.
    #[error(
        "no Vulkan loader found ({0}); install libvulkan1 and a driver such as mesa-vulkan-drivers"
    )]
    NoLoader(String),

    /// No physical device satisfied the requirements (the reasons for each rejection are listed).
    #[error("no usable Vulkan device: {0}")]
    NoDevice(String),

    /// Device memory could not be allocated.
    #[error("GPU memory allocation for {what} failed: {cause}")]
    Alloc {
        /// The resource, by its debug name.
        what: String,
        /// The allocator's own message.
        cause: String,
    },

    /// A shader interface or pipeline was inconsistent (a bug in vellum, reported rather than panicking).
    #[error("pipeline {name}: {msg}")]
    Pipeline {
        /// The shader or pipeline, as "render/raycast.comp".
        name: String,
        /// What was inconsistent.
        msg: String,
    },

    /// A file could not be opened, read or written.
    #[error("{}: {cause}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        cause: std::io::Error,
    },

    /// A file was read but its content is not what its format requires.
    #[error("{}: {msg}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong and what was expected.
        msg: String,
    },

    /// Float voxels that are NaN or infinite.
    #[error("{what} has {count} NaN or infinite voxels (64-bit values beyond ±3.4e38 do not fit the 32-bit floats vellum computes in); expected finite values")]
    NonFinite {
        /// The volume, by its file or role.
        what: String,
        /// How many voxels are not finite.
        count: usize,
    },

    /// The volume does not fit what the device supports.
    #[error("a volume of {}x{}x{} voxels exceeds the device: {limit}", dims[0], dims[1], dims[2])]
    TooLarge {
        /// Voxels along x, y, z.
        dims: [usize; 3],
        /// The device's limit that the volume exceeds.
        limit: String,
    },

    /// Any other input that does not make sense (bad flag values, malformed specs).
    #[error("{0}")]
    Invalid(String),

    /// The command was interrupted (Ctrl-C or SIGTERM): work stopped at its next step.
    #[error("interrupted")]
    Interrupted,
}

static INTERRUPTED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Asks every long loop that checks [`check_interrupt`] (the store writers' chunks, the chunked
/// passes) to stop at its next step: a signal handler's first move, so that no thread writes
/// into a temporary folder after it is removed.
pub fn interrupt() {
    INTERRUPTED.store(true, std::sync::atomic::Ordering::SeqCst);
}

/// Whether [`interrupt`] was called.
pub fn interrupted() -> bool {
    INTERRUPTED.load(std::sync::atomic::Ordering::SeqCst)
}

/// `Err(Error::Interrupted)` once [`interrupt`] was called.
pub fn check_interrupt() -> Result<()> {
    match interrupted() {
        true => Err(Error::Interrupted),
        false => Ok(()),
    }
}

/// The crate's result type.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// A format error for `path`.
    pub fn format(path: impl Into<PathBuf>, msg: impl Into<String>) -> Self {
        Error::Format {
            path: path.into(),
            msg: msg.into(),
        }
    }

    /// An I/O error for `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            cause: source,
        }
    }
}

/// A message as one line: control characters echoed from an input (a field name or a UID with a
/// newline in it) are escaped, so that an error is always one line on the terminal.
pub fn one_line(message: &str) -> String {
    message
        .chars()
        .flat_map(|c| match c {
            '\n' => vec!['\\', 'n'],
            '\r' => vec!['\\', 'r'],
            '\t' => vec!['\\', 't'],
            c if c.is_control() => c.escape_unicode().collect(),
            c => vec![c],
        })
        .collect()
}

/// The last line that is not blank in what a child process wrote to stderr: where its own
/// one-sentence error is.
pub fn last_line(stderr: &[u8]) -> String {
    String::from_utf8_lossy(stderr)
        .lines()
        .rev()
        .find(|l| !l.trim().is_empty())
        .unwrap_or("")
        .to_string()
}

#[cfg(test)]
mod one_line_tests {
    #[test]
    fn control_characters_are_escaped() {
        assert_eq!(super::one_line("a\nb\tc\u{7}"), "a\\nb\\tc\\u{7}");
        assert_eq!(super::one_line("plain"), "plain");
    }

    #[test]
    fn the_last_line_skips_blank_ones() {
        assert_eq!(super::last_line(b"warn\nerror: gone\n  \n"), "error: gone");
        assert_eq!(super::last_line(b""), "");
    }
}
