//! Counts debug-utils messages by severity. Tests fail on any error or warning, so the counter must
//! see everything the validation layer says, including during instance creation (the messenger is
//! chained into `VkInstanceCreateInfo` for that).

use ash::vk;
use std::ffi::CStr;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

/// Message counts by severity, plus the text of the first few errors and warnings.
#[derive(Debug, Default)]
pub(crate) struct MessageCounts {
    errors: AtomicUsize,
    warnings: AtomicUsize,
    infos: AtomicUsize,
    verbose: AtomicUsize,
    first: Mutex<Vec<String>>,
}

/// A copy of `MessageCounts` at one moment.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct MessageSnapshot {
    /// Errors reported.
    pub errors: usize,
    /// Warnings reported.
    pub warnings: usize,
    /// Informational messages.
    pub(crate) infos: usize,
    /// Verbose messages.
    pub verbose: usize,
    /// The text of the first errors and warnings (at most 16).
    pub messages: Vec<String>,
}

impl MessageSnapshot {
    /// True when there were no errors and no warnings.
    pub fn is_clean(&self) -> bool {
        self.errors == 0 && self.warnings == 0
    }
}

impl MessageCounts {
    /// Current counts.
    pub(crate) fn snapshot(&self) -> MessageSnapshot {
        MessageSnapshot {
            errors: self.errors.load(Ordering::SeqCst),
            warnings: self.warnings.load(Ordering::SeqCst),
            infos: self.infos.load(Ordering::SeqCst),
            verbose: self.verbose.load(Ordering::SeqCst),
            messages: self.first.lock().map(|m| m.clone()).unwrap_or_default(),
        }
    }

    fn record(&self, severity: vk::DebugUtilsMessageSeverityFlagsEXT, text: &str) {
        let counter = if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
            log::debug!("validation error: {text}");
            &self.errors
        } else if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::WARNING) {
            log::debug!("validation warning: {text}");
            &self.warnings
        } else if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::INFO) {
            log::debug!("vulkan: {text}");
            self.infos.fetch_add(1, Ordering::SeqCst);
            return;
        } else {
            log::trace!("vulkan: {text}");
            self.verbose.fetch_add(1, Ordering::SeqCst);
            return;
        };
        counter.fetch_add(1, Ordering::SeqCst);
        if let Ok(mut first) = self.first.lock() {
            if first.len() < 16 {
                first.push(text.to_string());
            }
        }
    }
}

/// The debug-utils callback. `user_data` points at the [`MessageCounts`] owned by the instance.
///
/// # Safety
/// Called by the Vulkan loader with valid pointers; `user_data` must be null or point at a live
/// `MessageCounts`.
pub(crate) unsafe extern "system" fn callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user_data: *mut std::ffi::c_void,
) -> vk::Bool32 {
    if data.is_null() || user_data.is_null() {
        return vk::FALSE;
    }
    let data = &*data;
    let text = if data.p_message.is_null() {
        String::from("(no message)")
    } else {
        CStr::from_ptr(data.p_message)
            .to_string_lossy()
            .into_owned()
    };
    let counts = &*(user_data as *const MessageCounts);
    counts.record(severity, &text);
    vk::FALSE
}
