//! One cache of compute pipelines, keyed by (shader, specialisation constants). The ray caster's
//! variants, line extraction's per-kind pipelines and the style passes take theirs from it: each
//! is compiled the first time a frame needs it and kept for the cache's life. The owner (the
//! renderer, or a tool that records passes itself) holds the cache and lends it by `&mut`, so no
//! lock hides a mutation behind `&self`.
//!
//! A hit allocates nothing: entries are found by the shader's name and then by a scan of its few
//! variants.

use crate::context::Context;
use crate::pipeline::{BindingKind, ComputePipeline};
use std::collections::HashMap;
use std::sync::Arc;
use vellum_error::{Error, Result};

/// What a compute pipeline is built from. The cache key is (`shader`, `constants`); the bindings
/// and push-constant size belong to the shader and must be the same at every use.
#[derive(Copy, Clone, Debug)]
pub struct PipelineDesc<'a> {
    /// Path under glsl/.
    pub shader: &'a str,
    /// The bindings of set 0, in binding order; a shader asked for with others is refused.
    pub bindings: &'a [BindingKind],
    /// Bytes of push constants.
    pub(crate) push_bytes: u32,
    /// Specialisation constants: `constants[i]` is `constant_id = i`.
    pub constants: &'a [u32],
}

impl<'a> PipelineDesc<'a> {
    /// A pipeline of `shader` with no specialisation constants.
    pub const fn new(shader: &'a str, bindings: &'a [BindingKind], push_bytes: u32) -> Self {
        PipelineDesc {
            shader,
            bindings,
            push_bytes,
            constants: &[],
        }
    }

    /// The same pipeline specialised with `constants`.
    pub const fn constants(self, constants: &'a [u32]) -> Self {
        PipelineDesc { constants, ..self }
    }
}

struct Entry {
    constants: Vec<u32>,
    bindings: Vec<BindingKind>,
    push_bytes: u32,
    pipeline: Arc<ComputePipeline>,
}

/// Compute pipelines built on first use and kept.
pub struct PipelineCache {
    ctx: Arc<Context>,
    by_shader: HashMap<String, Vec<Entry>>,
}

impl PipelineCache {
    /// An empty cache.
    pub fn new(ctx: &Arc<Context>) -> Self {
        PipelineCache {
            ctx: ctx.clone(),
            by_shader: HashMap::new(),
        }
    }

    /// The pipeline `desc` describes, built now if the cache does not hold it. Asking for a
    /// cached shader with other bindings or another push-constant size is an error: one shader
    /// has one interface.
    pub fn get(&mut self, desc: &PipelineDesc) -> Result<Arc<ComputePipeline>> {
        if let Some(entries) = self.by_shader.get(desc.shader) {
            if let Some(e) = entries.first() {
                if e.bindings != desc.bindings || e.push_bytes != desc.push_bytes {
                    return Err(Error::Invalid(format!(
                        "pipeline {} was cached with {} bindings and {} push-constant bytes, and is now asked for with {} and {}",
                        desc.shader,
                        e.bindings.len(),
                        e.push_bytes,
                        desc.bindings.len(),
                        desc.push_bytes
                    )));
                }
            }
            if let Some(e) = entries.iter().find(|e| e.constants == desc.constants) {
                return Ok(e.pipeline.clone());
            }
        }
        let pipeline = Arc::new(ComputePipeline::with_constants(
            &self.ctx,
            desc.shader,
            desc.bindings,
            desc.push_bytes,
            desc.constants,
        )?);
        self.by_shader
            .entry(desc.shader.to_string())
            .or_default()
            .push(Entry {
                constants: desc.constants.to_vec(),
                bindings: desc.bindings.to_vec(),
                push_bytes: desc.push_bytes,
                pipeline: pipeline.clone(),
            });
        Ok(pipeline)
    }

    /// Pipelines built so far.
    pub fn len(&self) -> usize {
        self.by_shader.values().map(Vec::len).sum()
    }

    /// Whether nothing has been built yet.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The context the pipelines are built on.
    pub fn context(&self) -> &Arc<Context> {
        &self.ctx
    }
}
