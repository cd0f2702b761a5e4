//! Vulkan results as vellum errors.

use vellum_error::{Error, Result};

/// Attaches a description of the call to a Vulkan result, as in `unsafe { dev.create_x(..) }.vk("creating x")?`.
pub(crate) trait VkContext<T> {
    /// Maps `Err(vk::Result)` to [`Error::Vulkan`] naming `what`.
    fn vk(self, what: impl Into<String>) -> Result<T>;
}

impl<T> VkContext<T> for std::result::Result<T, ash::vk::Result> {
    fn vk(self, what: impl Into<String>) -> Result<T> {
        self.map_err(|result| Error::Vulkan {
            what: what.into(),
            result: format!("{result}"),
        })
    }
}
