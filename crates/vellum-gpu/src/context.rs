//! The Vulkan instance, the chosen device and its allocator, shared through `Arc<Context>` by every
//! resource so that nothing outlives the device it was made on.
//!
//! ## Requirements
//! Vulkan 1.3 with dynamic rendering, synchronization2 and maintenance4 (Debian's shaderc emits
//! `LocalSizeId`, which needs maintenance4), plus `VK_KHR_push_descriptor`: every pass pushes its
//! descriptors, so there are no pools or sets to manage. Each device that lacks something is listed
//! with the reason, so `vellum devices` can say why a GPU was passed over.
//!
//! ## Validation
//! With validation on, `VK_LAYER_KHRONOS_validation` is enabled and a debug-utils messenger counts
//! messages by severity (`MessageCounts`). Tests assert the counts stay at zero.

use crate::lifetime::{Lifetimes, TransferCount};
use crate::validation::{self, MessageCounts, MessageSnapshot};
use crate::VkContext;
use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use std::ffi::{c_char, CStr, CString};
use std::mem::ManuallyDrop;
use std::sync::{Arc, Mutex};
use vellum_error::{Error, Result};

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// How to create a [`Context`]. `None` fields fall back to the environment.
#[derive(Clone, Debug, Default)]
pub struct ContextDesc {
    /// Enable the Khronos validation layer. Default: `VELLUM_VALIDATION` (1/0), else on in debug builds.
    pub validation: Option<bool>,
    /// Device index or case-insensitive name substring. Default: `VELLUM_DEVICE`, else the best type.
    pub device: Option<String>,
}

impl ContextDesc {
    /// Resolves the validation switch: explicit value, then `VELLUM_VALIDATION`, then debug/release.
    pub(crate) fn validation_enabled(&self) -> Result<bool> {
        if let Some(v) = self.validation {
            return Ok(v);
        }
        match std::env::var("VELLUM_VALIDATION")
            .ok()
            .as_deref()
            .map(str::trim)
        {
            Some("1" | "true" | "on" | "yes") => Ok(true),
            Some("0" | "false" | "off" | "no") => Ok(false),
            None | Some("") => Ok(cfg!(debug_assertions)),
            Some(other) => Err(Error::Invalid(format!(
                "VELLUM_VALIDATION={other:?} is not understood; expected 1 or 0 (or true/false, on/off, yes/no)"
            ))),
        }
    }

    /// Checks the environment switches every command reads (`VELLUM_VALIDATION`,
    /// `VELLUM_SYNC_VALIDATION`), so a misspelt value is refused by any command, not only by the
    /// ones that create a device.
    pub fn check_environment() -> Result<()> {
        ContextDesc::default().validation_enabled()?;
        match std::env::var("VELLUM_SYNC_VALIDATION")
            .ok()
            .as_deref()
            .map(str::trim)
        {
            None | Some("" | "0" | "1") => Ok(()),
            Some(other) => Err(Error::Invalid(format!(
                "VELLUM_SYNC_VALIDATION={other:?} is not understood; expected 1 (on) or 0 (off)"
            ))),
        }
    }

    /// Resolves the device selector: explicit value, then `VELLUM_DEVICE`.
    pub fn device_selector(&self) -> Option<String> {
        self.device
            .clone()
            .or_else(|| std::env::var("VELLUM_DEVICE").ok())
            .filter(|s| !s.trim().is_empty())
    }
}

/// What a window needs from the instance and device: the surface extensions the windowing system
/// asks for (`ash_window::enumerate_required_extensions`) and `VK_KHR_swapchain`.
#[derive(Clone, Debug, Default)]
pub struct Presentation {
    /// Instance extensions for surfaces on this display.
    pub(crate) instance_extensions: Vec<&'static CStr>,
    /// Enable `VK_KHR_swapchain` on the device (a device without it is rejected, with the reason).
    pub swapchain: bool,
}

/// A physical device as seen during selection.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DeviceCandidate {
    /// Index among the physical devices, as `--device` takes it.
    pub index: usize,
    /// The device's name, as the driver reports it.
    pub name: String,
    /// Discrete, integrated, virtual or CPU.
    pub device_type: String,
    /// The Vulkan version the device supports, as "1.3.280".
    pub api_version: String,
    /// The driver's name and version.
    pub driver: String,
    /// Why the device cannot be used, or `None` when it meets every requirement.
    pub rejected: Option<String>,
}

/// Properties and limits of the chosen device that passes need.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DeviceInfo {
    /// The device's name, as the driver reports it.
    pub name: String,
    /// Discrete, integrated, virtual or CPU.
    pub device_type: String,
    /// The Vulkan version the device supports.
    pub api_version: String,
    /// The driver's name and version.
    pub driver: String,
    /// The largest 3D image edge in texels.
    pub max_image_dimension_3d: u32,
    /// The largest 2D image edge in texels.
    pub max_image_dimension_2d: u32,
    /// The largest storage buffer range in bytes.
    pub max_storage_buffer_range: u32,
    /// The largest dispatch along x, y, z in workgroups.
    pub(crate) max_compute_work_group_count: [u32; 3],
    /// Nanoseconds per timestamp tick.
    pub(crate) timestamp_period_ns: f32,
    /// Size of the largest device-local heap in bytes.
    pub device_local_heap_bytes: u64,
    /// The most bytes one allocation may take (Vulkan 1.1's `maxMemoryAllocationSize`; 2 GiB on
    /// lavapipe): an image larger than that cannot be made, whatever the heap holds.
    pub max_memory_allocation_bytes: u64,
    /// Alignment of uniform-buffer offsets.
    pub(crate) min_uniform_buffer_offset_alignment: u64,
    /// Bytes of shared memory a compute workgroup may declare.
    pub max_compute_shared_memory: u32,
    /// Whether storage images may use the extended formats (RG32F among them); enabled when true.
    pub storage_image_extended_formats: bool,
}

impl DeviceInfo {
    /// A choice a GPU makes and a CPU rasteriser does not (one whose lanes pay for work a GPU
    /// hides): on unless this is a CPU device, with `var=0|1` overriding it, for measuring.
    pub fn on_gpu_unless(&self, var: &str) -> bool {
        match std::env::var(var).ok().as_deref() {
            Some("0") => false,
            Some("1") => true,
            _ => self.device_type != "CPU",
        }
    }
}

/// The instance, device, queue and allocator. Create once, share as `Arc<Context>`.
pub struct Context {
    /// The Vulkan loader.
    pub entry: ash::Entry,
    /// The instance.
    pub instance: ash::Instance,
    debug_instance: Option<ash::ext::debug_utils::Instance>,
    messenger: vk::DebugUtilsMessengerEXT,
    /// Present when debug utils are available: object names and command-buffer labels.
    pub(crate) debug_utils: Option<ash::ext::debug_utils::Device>,
    /// The chosen physical device.
    pub physical: vk::PhysicalDevice,
    /// The logical device.
    pub device: ash::Device,
    /// The push-descriptor functions every pipeline binds its resources with.
    pub(crate) push_descriptor: ash::khr::push_descriptor::Device,
    /// The family of the one queue.
    pub(crate) queue_family: u32,
    queue: Mutex<vk::Queue>,
    /// Shared (an `Arc`) so that egui's renderer can allocate through it; every holder is dropped
    /// before the context (the viewer drops its egui renderer first).
    allocator: ManuallyDrop<Arc<Mutex<Allocator>>>,
    /// Properties and limits of the chosen device.
    pub info: DeviceInfo,
    /// Every physical device, with the reason it was rejected where it was.
    pub candidates: Vec<DeviceCandidate>,
    /// Index into `candidates` of the chosen device.
    pub chosen: usize,
    /// Whether the Khronos validation layer is on.
    pub validation: bool,
    // Boxed so that the pointer handed to the messenger stays put; dropped after the messenger.
    messages: Box<MessageCounts>,
    /// Submission serials, deferred release and resource accounting (see `gpu/lifetime.rs`).
    lifetimes: Lifetimes<Garbage>,
    /// Created with `VK_KHR_swapchain`.
    presentation: bool,
}

impl std::fmt::Debug for Context {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Context")
            .field("device", &self.info.name)
            .field("validation", &self.validation)
            .finish()
    }
}

/// Opens the loader, turning "no libvulkan" into a sentence rather than a panic.
fn load_entry() -> Result<ash::Entry> {
    // SAFETY: loading the system Vulkan loader runs its initialisers, which is what it is for.
    unsafe { ash::Entry::load() }.map_err(|e| Error::NoLoader(e.to_string()))
}

fn messenger_info(counts: &MessageCounts) -> vk::DebugUtilsMessengerCreateInfoEXT<'static> {
    vk::DebugUtilsMessengerCreateInfoEXT::default()
        .message_severity(
            vk::DebugUtilsMessageSeverityFlagsEXT::ERROR
                | vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
                | vk::DebugUtilsMessageSeverityFlagsEXT::INFO,
        )
        .message_type(
            vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
        )
        .pfn_user_callback(Some(validation::callback))
        .user_data(counts as *const MessageCounts as *mut std::ffi::c_void)
}

/// Environment variables through which a user points the Vulkan loader at driver manifests.
const DRIVER_VARS: [&str; 3] = ["VK_DRIVER_FILES", "VK_ICD_FILENAMES", "VK_ADD_DRIVER_FILES"];

/// Checks the driver manifests named by [`DRIVER_VARS`]: the loader turns a missing or malformed
/// manifest into an unrelated error (often "out of host memory"), so when it fails we look for
/// the cause ourselves. Returns a sentence naming the variable, the file and what is wrong.
fn driver_manifest_problem() -> Option<String> {
    for var in DRIVER_VARS {
        let Some(value) = std::env::var_os(var) else {
            continue;
        };
        for path in std::env::split_paths(&value) {
            if path.as_os_str().is_empty() || path.is_dir() {
                continue;
            }
            let shown = path.display();
            let text = match std::fs::read_to_string(&path) {
                Ok(t) => t,
                Err(e) => return Some(format!("{var} names {shown}, which cannot be read ({e})")),
            };
            let json: serde_json::Value = match serde_json::from_str(&text) {
                Ok(j) => j,
                Err(e) => {
                    return Some(format!(
                        "{var} names {shown}, which is not a valid driver manifest: its JSON is broken ({e})"
                    ))
                }
            };
            if json
                .pointer("/ICD/library_path")
                .and_then(|v| v.as_str())
                .is_none()
            {
                return Some(format!(
                    "{var} names {shown}, which is not a valid driver manifest: it has no ICD.library_path"
                ));
            }
        }
    }
    None
}

/// Replaces a loader failure by the driver manifest problem behind it, when there is one.
fn explain_loader_failure(e: Error) -> Error {
    match (&e, driver_manifest_problem()) {
        (Error::Vulkan { .. } | Error::NoDevice(_), Some(problem)) => Error::NoDevice(format!(
            "the Vulkan loader could not load a driver: {problem}; expected a valid manifest, or the variable unset"
        )),
        _ => e,
    }
}

fn create_instance(
    entry: &ash::Entry,
    validation: bool,
    counts: &MessageCounts,
    extra: &[&CStr],
) -> Result<(ash::Instance, bool)> {
    create_instance_inner(entry, validation, counts, extra).map_err(explain_loader_failure)
}

fn create_instance_inner(
    entry: &ash::Entry,
    validation: bool,
    counts: &MessageCounts,
    extra: &[&CStr],
) -> Result<(ash::Instance, bool)> {
    // SAFETY: plain enumeration calls on a loaded entry.
    let layers =
        unsafe { entry.enumerate_instance_layer_properties() }.vk("listing instance layers")?;
    let has_layer = |name: &CStr| layers.iter().any(|l| l.layer_name_as_c_str() == Ok(name));
    if validation && !has_layer(VALIDATION_LAYER) {
        return Err(Error::NoDevice(
            "validation was requested but VK_LAYER_KHRONOS_validation is not installed; install \
             vulkan-validationlayers or set VELLUM_VALIDATION=0"
                .into(),
        ));
    }
    let exts = unsafe { entry.enumerate_instance_extension_properties(None) }
        .vk("listing instance extensions")?;
    let has_debug_utils = exts
        .iter()
        .any(|e| e.extension_name_as_c_str() == Ok(ash::ext::debug_utils::NAME));

    let app_name = c"vellum";
    let app = vk::ApplicationInfo::default()
        .application_name(app_name)
        .application_version(vk::make_api_version(0, 0, 1, 0))
        .engine_name(app_name)
        .api_version(vk::API_VERSION_1_3);
    let layer_ptrs: Vec<*const c_char> = if validation {
        vec![VALIDATION_LAYER.as_ptr()]
    } else {
        vec![]
    };
    let mut ext_ptrs: Vec<*const c_char> = if has_debug_utils {
        vec![ash::ext::debug_utils::NAME.as_ptr()]
    } else {
        vec![]
    };
    for e in extra {
        if !exts.iter().any(|x| x.extension_name_as_c_str() == Ok(*e)) {
            return Err(Error::NoDevice(format!(
                "the Vulkan instance lacks {} which this window system needs; install the Vulkan loader and a driver with surface support",
                e.to_string_lossy()
            )));
        }
        ext_ptrs.push(e.as_ptr());
    }
    // VELLUM_SYNC_VALIDATION=1 adds the layer's synchronization validation, which reports missing
    // or wrong barriers (hazards) that the default checks do not.
    let sync = validation && std::env::var("VELLUM_SYNC_VALIDATION").is_ok_and(|v| v.trim() == "1");
    if sync {
        let layer_exts =
            unsafe { entry.enumerate_instance_extension_properties(Some(VALIDATION_LAYER)) }
                .vk("listing the validation layer's extensions")?;
        if layer_exts
            .iter()
            .any(|e| e.extension_name_as_c_str() == Ok(ash::ext::validation_features::NAME))
        {
            ext_ptrs.push(ash::ext::validation_features::NAME.as_ptr());
        }
    }
    let enables = [vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION];
    let mut features = vk::ValidationFeaturesEXT::default().enabled_validation_features(&enables);
    let mut chained = messenger_info(counts);
    let mut info = vk::InstanceCreateInfo::default()
        .application_info(&app)
        .enabled_layer_names(&layer_ptrs)
        .enabled_extension_names(&ext_ptrs);
    if has_debug_utils {
        info = info.push_next(&mut chained);
    }
    if sync && ext_ptrs.contains(&ash::ext::validation_features::NAME.as_ptr()) {
        info = info.push_next(&mut features);
    }
    // SAFETY: every pointer in `info` outlives the call.
    let instance = match unsafe { entry.create_instance(&info, None) } {
        Ok(i) => i,
        Err(vk::Result::ERROR_INCOMPATIBLE_DRIVER) => {
            return Err(Error::NoDevice(
                "the Vulkan loader found no driver; install mesa-vulkan-drivers (lavapipe) or a GPU driver".into(),
            ))
        }
        Err(result) => {
            return Err(Error::Vulkan { what: "creating the Vulkan instance".into(), result: format!("{result}") })
        }
    };
    Ok((instance, has_debug_utils))
}

fn type_name(t: vk::PhysicalDeviceType) -> &'static str {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => "discrete GPU",
        vk::PhysicalDeviceType::INTEGRATED_GPU => "integrated GPU",
        vk::PhysicalDeviceType::VIRTUAL_GPU => "virtual GPU",
        vk::PhysicalDeviceType::CPU => "CPU",
        _ => "other",
    }
}

fn version_string(v: u32) -> String {
    format!(
        "{}.{}.{}",
        vk::api_version_major(v),
        vk::api_version_minor(v),
        vk::api_version_patch(v)
    )
}

/// Examines one physical device: its description and, if it cannot be used, why.
fn examine(
    instance: &ash::Instance,
    pd: vk::PhysicalDevice,
    index: usize,
    presentation: bool,
) -> Result<(DeviceCandidate, Option<u32>)> {
    let mut driver = vk::PhysicalDeviceDriverProperties::default();
    let mut props2 = vk::PhysicalDeviceProperties2::default().push_next(&mut driver);
    // SAFETY: `pd` came from this instance; the chain outlives the call.
    unsafe { instance.get_physical_device_properties2(pd, &mut props2) };
    let props = props2.properties;
    let name = props
        .device_name_as_c_str()
        .map(|c| c.to_string_lossy().into_owned())
        .unwrap_or_default();
    let driver_name = driver
        .driver_name_as_c_str()
        .map(|c| c.to_string_lossy().into_owned())
        .unwrap_or_default();
    let driver_info = driver
        .driver_info_as_c_str()
        .map(|c| c.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut reasons = Vec::new();
    let mut queue_family = None;
    if props.api_version < vk::API_VERSION_1_3 {
        reasons.push(format!(
            "supports Vulkan {} but 1.3 is required",
            version_string(props.api_version)
        ));
    } else {
        let mut f13 = vk::PhysicalDeviceVulkan13Features::default();
        let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut f13);
        unsafe { instance.get_physical_device_features2(pd, &mut f2) };
        let core = f2.features;
        for (ok, what) in [
            (core.independent_blend, "independentBlend"),
            (f13.dynamic_rendering, "dynamicRendering"),
            (f13.synchronization2, "synchronization2"),
            (f13.maintenance4, "maintenance4"),
        ] {
            if ok == vk::FALSE {
                reasons.push(format!("lacks the {what} feature"));
            }
        }
    }
    let exts = unsafe { instance.enumerate_device_extension_properties(pd) }
        .vk("listing device extensions")?;
    if !exts
        .iter()
        .any(|e| e.extension_name_as_c_str() == Ok(ash::khr::push_descriptor::NAME))
    {
        reasons.push("lacks VK_KHR_push_descriptor".into());
    }
    if presentation
        && !exts
            .iter()
            .any(|e| e.extension_name_as_c_str() == Ok(ash::khr::swapchain::NAME))
    {
        reasons.push("lacks VK_KHR_swapchain (it cannot present to a window)".into());
    }
    let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
    let wanted = vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE;
    match families
        .iter()
        .position(|f| f.queue_flags.contains(wanted) && f.timestamp_valid_bits > 0)
    {
        Some(i) => queue_family = Some(i as u32),
        None => reasons.push("has no graphics+compute queue with timestamps".into()),
    }
    let candidate = DeviceCandidate {
        index,
        name,
        device_type: type_name(props.device_type).into(),
        api_version: version_string(props.api_version),
        driver: format!("{driver_name} {driver_info}").trim().to_string(),
        rejected: (!reasons.is_empty()).then(|| reasons.join("; ")),
    };
    Ok((candidate, queue_family))
}

fn type_rank(t: &str) -> u32 {
    match t {
        "discrete GPU" => 0,
        "integrated GPU" => 1,
        "virtual GPU" => 2,
        "CPU" => 3,
        _ => 4,
    }
}

/// Picks a candidate by selector (index or name substring), or the best usable type.
fn choose(candidates: &[DeviceCandidate], selector: Option<&str>) -> Result<usize> {
    let usable: Vec<&DeviceCandidate> =
        candidates.iter().filter(|c| c.rejected.is_none()).collect();
    let listing = || {
        candidates
            .iter()
            .map(|c| {
                format!(
                    "[{}] {}{}",
                    c.index,
                    c.name,
                    c.rejected
                        .as_ref()
                        .map(|r| format!(" (rejected: {r})"))
                        .unwrap_or_default()
                )
            })
            .collect::<Vec<_>>()
            .join(", ")
    };
    if candidates.is_empty() {
        return Err(Error::NoDevice(
            "the Vulkan loader reports no physical devices; install a driver such as mesa-vulkan-drivers (lavapipe)".into(),
        ));
    }
    match selector {
        Some(sel) => {
            let sel = sel.trim();
            let found = if let Ok(i) = sel.parse::<usize>() {
                candidates.iter().find(|c| c.index == i)
            } else {
                let lower = sel.to_lowercase();
                candidates
                    .iter()
                    .find(|c| c.rejected.is_none() && c.name.to_lowercase().contains(&lower))
                    .or_else(|| {
                        candidates
                            .iter()
                            .find(|c| c.name.to_lowercase().contains(&lower))
                    })
            };
            match found {
                Some(c) if c.rejected.is_none() => Ok(c.index),
                Some(c) => Err(Error::NoDevice(format!(
                    "device '{sel}' ({}) cannot be used: {}",
                    c.name,
                    c.rejected.as_deref().unwrap_or("")
                ))),
                None => Err(Error::NoDevice(format!(
                    "no device matches '{sel}'; expected an index or part of a name among: {}",
                    listing()
                ))),
            }
        }
        None => usable
            .iter()
            .min_by_key(|c| (type_rank(&c.device_type), c.index))
            .map(|c| c.index)
            .ok_or_else(|| {
                Error::NoDevice(format!("no device meets the requirements: {}", listing()))
            }),
    }
}

/// Lists the physical devices without creating a logical device (for `vellum devices`).
pub fn probe_devices(desc: &ContextDesc) -> Result<(Vec<DeviceCandidate>, Option<usize>)> {
    let entry = load_entry()?;
    let counts = MessageCounts::default();
    let (instance, _) = create_instance(&entry, false, &counts, &[])?;
    let result = (|| {
        let pds = unsafe { instance.enumerate_physical_devices() }
            .vk("listing physical devices")
            .map_err(explain_loader_failure)?;
        let candidates = pds
            .iter()
            .enumerate()
            .map(|(i, &pd)| examine(&instance, pd, i, false).map(|(c, _)| c))
            .collect::<Result<Vec<_>>>()?;
        let chosen = choose(&candidates, desc.device_selector().as_deref()).ok();
        Ok((candidates, chosen))
    })();
    // SAFETY: no child objects were created.
    unsafe { instance.destroy_instance(None) };
    result
}

impl Context {
    /// Creates the instance and the chosen device.
    pub fn new(desc: &ContextDesc) -> Result<Arc<Context>> {
        Self::with_presentation(desc, &Presentation::default())
    }

    /// Creates the instance and the chosen device with what a window needs (`present`).
    pub fn with_presentation(desc: &ContextDesc, present: &Presentation) -> Result<Arc<Context>> {
        let validation = desc.validation_enabled()?;
        let entry = load_entry()?;
        let messages = Box::new(MessageCounts::default());
        let (instance, has_debug_utils) =
            create_instance(&entry, validation, &messages, &present.instance_extensions)?;
        // From here on, failures must destroy what exists: a guard struct would be heavier than
        // this closure-and-cleanup pair.
        let made = Self::finish(
            entry.clone(),
            instance.clone(),
            has_debug_utils,
            validation,
            messages,
            desc,
            present.swapchain,
        );
        if made.is_err() {
            // SAFETY: `finish` destroyed everything it created before returning its error.
            unsafe { instance.destroy_instance(None) };
        }
        made
    }

    fn finish(
        entry: ash::Entry,
        instance: ash::Instance,
        has_debug_utils: bool,
        validation: bool,
        messages: Box<MessageCounts>,
        desc: &ContextDesc,
        presentation: bool,
    ) -> Result<Arc<Context>> {
        let (debug_instance, messenger) = if has_debug_utils {
            let di = ash::ext::debug_utils::Instance::new(&entry, &instance);
            let m = unsafe { di.create_debug_utils_messenger(&messenger_info(&messages), None) }
                .vk("creating the debug messenger")?;
            (Some(di), m)
        } else {
            (None, vk::DebugUtilsMessengerEXT::null())
        };
        let opened = match open_device(&instance, desc, presentation) {
            Ok(o) => o,
            Err(e) => {
                if let Some(di) = &debug_instance {
                    unsafe { di.destroy_debug_utils_messenger(messenger, None) };
                }
                return Err(e);
            }
        };
        let OpenedDevice {
            candidates,
            chosen,
            physical,
            queue_family,
            device,
            allocator,
            info,
        } = opened;
        let queue = unsafe { device.get_device_queue(queue_family, 0) };
        let debug_utils =
            has_debug_utils.then(|| ash::ext::debug_utils::Device::new(&instance, &device));
        let push_descriptor = ash::khr::push_descriptor::Device::new(&instance, &device);
        Ok(Arc::new(Context {
            entry,
            instance,
            debug_instance,
            messenger,
            debug_utils,
            physical,
            device,
            push_descriptor,
            queue_family,
            queue: Mutex::new(queue),
            allocator: ManuallyDrop::new(Arc::new(Mutex::new(allocator))),
            info,
            candidates,
            chosen,
            validation,
            messages,
            lifetimes: Default::default(),
            presentation,
        }))
    }

    /// Says on stderr if the validation layer complained (the messages themselves are logged at
    /// debug level: `-vv`). The tools call it before they exit; tests read [`Context::messages`].
    pub fn report_validation(&self) {
        let m = self.messages();
        if !m.is_clean() {
            eprintln!(
                "warning: the Vulkan validation layer reported {} error(s) and {} warning(s); run with -vv to see them",
                m.errors, m.warnings
            );
        }
    }

    /// Validation messages counted so far.
    pub fn messages(&self) -> MessageSnapshot {
        self.messages.snapshot()
    }

    /// The allocator (locked for the duration of one allocation or free).
    pub(crate) fn allocator(&self) -> std::sync::MutexGuard<'_, Allocator> {
        // A poisoned lock means a panic happened mid-allocation elsewhere; the allocator itself is
        // still consistent, so carry on.
        self.allocator.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The allocator, shared, for libraries that allocate through gpu-allocator themselves (egui's
    /// renderer). Drop every clone before the context.
    pub fn shared_allocator(&self) -> Arc<Mutex<Allocator>> {
        Arc::clone(&self.allocator)
    }

    /// Whether the device was created with `VK_KHR_swapchain`.
    pub(crate) fn can_present(&self) -> bool {
        self.presentation
    }

    /// The queue's handle, for a library that submits by itself (egui's texture uploads) on this
    /// thread between our frames.
    pub fn queue_handle(&self) -> vk::Queue {
        *self.queue()
    }

    /// The queue, locked for one submission.
    pub fn queue(&self) -> std::sync::MutexGuard<'_, vk::Queue> {
        self.queue.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Names a Vulkan object for validation messages and captures (no-op without debug utils).
    pub(crate) fn set_name<H: vk::Handle>(&self, handle: H, name: &str) {
        if let Some(du) = &self.debug_utils {
            if let Ok(cname) = CString::new(name) {
                let info = vk::DebugUtilsObjectNameInfoEXT::default()
                    .object_handle(handle)
                    .object_name(&cname);
                // Naming is best effort: a failure here must not fail the work.
                let _ = unsafe { du.set_debug_utils_object_name(&info) };
            }
        }
    }

    /// Opens a debug label region in `cmd`.
    pub(crate) fn begin_label(&self, cmd: vk::CommandBuffer, name: &str) {
        if let Some(du) = &self.debug_utils {
            if let Ok(cname) = CString::new(name) {
                let label = vk::DebugUtilsLabelEXT::default().label_name(&cname);
                unsafe { du.cmd_begin_debug_utils_label(cmd, &label) };
            }
        }
    }

    /// Closes the label region opened by [`Context::begin_label`].
    pub(crate) fn end_label(&self, cmd: vk::CommandBuffer) {
        if let Some(du) = &self.debug_utils {
            unsafe { du.cmd_end_debug_utils_label(cmd) };
        }
    }

    /// Whether compute shaders may write images of `format` as storage images with optimal
    /// tiling on this device.
    pub fn can_write_storage(&self, format: vk::Format) -> bool {
        let props = unsafe {
            self.instance
                .get_physical_device_format_properties(self.physical, format)
        };
        props
            .optimal_tiling_features
            .contains(vk::FormatFeatureFlags::STORAGE_IMAGE)
    }

    /// Checks that a 3D image of `dims` with `bytes_per_voxel` fits the device's limits. `copies` is
    /// how many such images the caller will hold at once (for the memory estimate).
    pub fn check_image_3d(
        &self,
        dims: [usize; 3],
        bytes_per_voxel: usize,
        copies: usize,
    ) -> Result<()> {
        let max = self.info.max_image_dimension_3d as usize;
        if dims.iter().any(|&d| d > max) {
            return Err(Error::TooLarge {
                dims,
                limit: format!(
                    "{} allows at most {max} voxels along each axis of a 3D image",
                    self.info.name
                ),
            });
        }
        let bytes =
            dims.iter().product::<usize>() as u128 * bytes_per_voxel as u128 * copies as u128;
        if bytes > self.info.device_local_heap_bytes as u128 {
            return Err(Error::TooLarge {
                dims,
                limit: format!(
                    "{copies} image(s) of {bytes_per_voxel} byte(s) per voxel need {:.1} MiB but the device heap holds {:.1} MiB",
                    bytes as f64 / 1048576.0,
                    self.info.device_local_heap_bytes as f64 / 1048576.0
                ),
            });
        }
        Ok(())
    }
}

/// The chosen device, opened: the candidates it was chosen from, its queue family, the logical
/// device, its allocator and what the passes need to know of it.
struct OpenedDevice {
    candidates: Vec<DeviceCandidate>,
    chosen: usize,
    physical: vk::PhysicalDevice,
    queue_family: u32,
    device: ash::Device,
    allocator: Allocator,
    info: DeviceInfo,
}

/// Examines every physical device, chooses one (`desc`'s selector, else the best) and opens it.
/// On an error nothing it made is left behind.
fn open_device(
    instance: &ash::Instance,
    desc: &ContextDesc,
    presentation: bool,
) -> Result<OpenedDevice> {
    let pds = unsafe { instance.enumerate_physical_devices() }
        .vk("listing physical devices")
        .map_err(explain_loader_failure)?;
    let mut candidates = Vec::new();
    let mut families = Vec::new();
    for (i, &pd) in pds.iter().enumerate() {
        let (c, f) = examine(instance, pd, i, presentation)?;
        if let Some(r) = &c.rejected {
            log::info!("device [{i}] {} rejected: {r}", c.name);
        }
        candidates.push(c);
        families.push(f);
    }
    let chosen = choose(&candidates, desc.device_selector().as_deref())?;
    let physical = pds[chosen];
    let queue_family = families[chosen].expect("a usable device has a queue family");
    let (device, extended_formats) =
        create_logical_device(instance, physical, queue_family, presentation)?;
    let allocator = Allocator::new(&AllocatorCreateDesc {
        instance: instance.clone(),
        device: device.clone(),
        physical_device: physical,
        debug_settings: Default::default(),
        buffer_device_address: false,
        allocation_sizes: Default::default(),
    });
    let allocator = match allocator {
        Ok(a) => a,
        Err(cause) => {
            unsafe { device.destroy_device(None) };
            return Err(Error::Alloc {
                what: "the allocator".into(),
                cause: cause.to_string(),
            });
        }
    };
    let info = device_info(instance, physical, &candidates[chosen], extended_formats);
    log::info!(
        "using device [{chosen}] {} ({}, {})",
        info.name,
        info.device_type,
        info.driver
    );
    Ok(OpenedDevice {
        candidates,
        chosen,
        physical,
        queue_family,
        device,
        allocator,
        info,
    })
}

/// The logical device with one queue of `queue_family`, the features the passes use, push
/// descriptors and (with `presentation`) the swapchain. Returns it and whether storage images
/// of the extended formats are enabled.
fn create_logical_device(
    instance: &ash::Instance,
    physical: vk::PhysicalDevice,
    queue_family: u32,
    presentation: bool,
) -> Result<(ash::Device, bool)> {
    let priorities = [1.0f32];
    let queue_info = [vk::DeviceQueueCreateInfo::default()
        .queue_family_index(queue_family)
        .queue_priorities(&priorities)];
    let mut f13 = vk::PhysicalDeviceVulkan13Features::default()
        .dynamic_rendering(true)
        .synchronization2(true)
        .maintenance4(true);
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
    // independentBlend: the focus pass blends two targets and replaces the third.
    // shaderStorageImageExtendedFormats where offered: the FFT occlusion's complex fields are
    // RG32F storage images (passes/occlusion_fft/gpu.rs says so when it is missing).
    let extended_formats = unsafe { instance.get_physical_device_features(physical) }
        .shader_storage_image_extended_formats
        == vk::TRUE;
    let mut f2 = vk::PhysicalDeviceFeatures2::default().features(
        vk::PhysicalDeviceFeatures::default()
            .independent_blend(true)
            .shader_storage_image_extended_formats(extended_formats),
    );
    let mut ext_ptrs = vec![ash::khr::push_descriptor::NAME.as_ptr()];
    if presentation {
        ext_ptrs.push(ash::khr::swapchain::NAME.as_ptr());
    }
    let info = vk::DeviceCreateInfo::default()
        .queue_create_infos(&queue_info)
        .enabled_extension_names(&ext_ptrs)
        .push_next(&mut f2)
        .push_next(&mut f12)
        .push_next(&mut f13);
    let device = unsafe { instance.create_device(physical, &info, None) }
        .vk("creating the logical device")?;
    Ok((device, extended_formats))
}

/// What the passes need to know of the chosen device `c`.
fn device_info(
    instance: &ash::Instance,
    physical: vk::PhysicalDevice,
    c: &DeviceCandidate,
    extended_formats: bool,
) -> DeviceInfo {
    let props = unsafe { instance.get_physical_device_properties(physical) };
    let mut maintenance3 = vk::PhysicalDeviceMaintenance3Properties::default();
    let mut props2 = vk::PhysicalDeviceProperties2::default().push_next(&mut maintenance3);
    unsafe { instance.get_physical_device_properties2(physical, &mut props2) };
    let max_memory_allocation_bytes = maintenance3.max_memory_allocation_size;
    let mem = unsafe { instance.get_physical_device_memory_properties(physical) };
    let device_local_heap_bytes = mem.memory_heaps[..mem.memory_heap_count as usize]
        .iter()
        .filter(|h| h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL))
        .map(|h| h.size)
        .max()
        .unwrap_or(0);
    DeviceInfo {
        name: c.name.clone(),
        device_type: c.device_type.clone(),
        api_version: c.api_version.clone(),
        driver: c.driver.clone(),
        max_image_dimension_3d: props.limits.max_image_dimension3_d,
        max_image_dimension_2d: props.limits.max_image_dimension2_d,
        max_storage_buffer_range: props.limits.max_storage_buffer_range,
        max_compute_work_group_count: props.limits.max_compute_work_group_count,
        timestamp_period_ns: props.limits.timestamp_period,
        device_local_heap_bytes,
        max_memory_allocation_bytes,
        min_uniform_buffer_offset_alignment: props.limits.min_uniform_buffer_offset_alignment,
        max_compute_shared_memory: props.limits.max_compute_shared_memory_size,
        storage_image_extended_formats: extended_formats,
    }
}

/// Work that destroys handles and frees memory, run once the GPU is done with them.
pub(crate) type Garbage = Box<dyn FnOnce(&Context) + Send>;

/// Deferred release and accounting (`lifetime.rs` holds the serials, the list and the counters).
impl Context {
    /// Destroys `garbage` now if no submitted or recording work can use it, else once the newest
    /// such work has completed.
    pub(crate) fn retire(&self, garbage: Garbage) {
        if let Some(now) = self.lifetimes.retire(garbage) {
            now(self);
        }
    }

    /// Marks the start of recording a command buffer that will be submitted; `what` names it.
    /// One recording at a time per context (see `lifetime.rs`): a second is refused.
    pub(crate) fn begin_recording(&self, what: &str) -> Result<()> {
        self.lifetimes.begin_recording(what)
    }

    /// Marks the end of recording (after the submission, or after abandoning the commands).
    pub(crate) fn end_recording(&self) {
        self.lifetimes.end_recording()
    }

    /// The serial of a submission about to be made.
    pub(crate) fn next_serial(&self) -> u64 {
        self.lifetimes.next_serial()
    }

    /// Records that submission `serial` (and every earlier one) has completed, and frees the
    /// garbage it held back.
    pub(crate) fn mark_completed(&self, serial: u64) {
        for garbage in self.lifetimes.mark_completed(serial) {
            garbage(self);
        }
    }

    /// Objects waiting for their submission to complete before they are freed.
    pub fn pending_releases(&self) -> usize {
        self.lifetimes.pending_releases()
    }

    pub(crate) fn count_allocation(&self, bytes: u64) {
        self.lifetimes.count_allocation(bytes)
    }

    /// Notes `bytes` of GPU memory freed.
    pub(crate) fn count_free(&self, bytes: u64) {
        self.lifetimes.count_free(bytes)
    }

    /// Bytes of GPU memory allocated through the allocator now.
    pub fn allocated_bytes(&self) -> u64 {
        self.lifetimes.allocated_bytes()
    }

    /// The most bytes of GPU memory allocated through the allocator at any time.
    pub fn peak_allocated_bytes(&self) -> u64 {
        self.lifetimes.peak_allocated_bytes()
    }

    /// GPU memory allocations made through the allocator since the context was created.
    pub fn allocation_count(&self) -> u64 {
        self.lifetimes.allocation_count()
    }

    /// Notes a recorded host transfer of `bytes` to (`upload`) or from the resource `name`.
    pub fn count_transfer(&self, name: &str, upload: bool, bytes: u64) {
        self.lifetimes.count_transfer(name, upload, bytes)
    }

    /// Host transfers recorded so far, by resource name.
    pub fn transfers(&self) -> std::collections::BTreeMap<String, TransferCount> {
        self.lifetimes.transfers()
    }
}

impl Drop for Context {
    fn drop(&mut self) {
        // SAFETY: every resource holds an Arc<Context>, so by now all of them are gone; waiting for
        // idle covers work that was submitted and not waited on.
        unsafe {
            let _ = self.device.device_wait_idle();
            for garbage in self.lifetimes.drain_all() {
                garbage(self);
            }
            if Arc::strong_count(&self.allocator) > 1 {
                log::error!("the allocator is still shared while the context is dropped");
            }
            ManuallyDrop::drop(&mut self.allocator);
            self.device.destroy_device(None);
            if let Some(di) = &self.debug_instance {
                di.destroy_debug_utils_messenger(self.messenger, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}
