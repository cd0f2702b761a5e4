//! Frame assembly and the renderers: the view and its camera (`view`), the uniforms the shaders
//! share (`shading`), the persistent layers (`targets`), one frame from setup to recorded passes
//! (`frame`), the slicer and the ray caster that draw the levels, the style passes (`post`,
//! `style`), proxy geometry and the scene file. `view`, `camera`, `proxy`, `style` and `scene`'s
//! data are plain CPU; the rest record Vulkan passes through `gpu/`.

pub mod bricked;
pub mod camera;
pub mod frame;
pub mod overrides;
pub mod pick;
pub(crate) mod post;
pub(crate) mod proxy;
pub mod raycast;
pub mod scene;
pub mod session;
pub(crate) mod shading;
pub(crate) mod slicer;
pub mod sortlast;
pub mod stream;
pub mod style;
pub mod targets;
pub mod view;
