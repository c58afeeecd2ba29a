//! The executor. A model graph is recorded once into a [`PlanBuilder`] as a list of ops (kernel, params,
//! tensor bindings, dispatch size). [`PlanBuilder::build`] then
//! - gives every transient tensor a pooled buffer, reusing a buffer once the tensors in it are dead
//!   (liveness over the op list), and reports the planned peak bytes;
//! - writes all ops' params into one uniform buffer;
//! - fetches the cached pipelines and creates every bind group.
//!
//! Executing a plan (`plan/execute.rs`) records all ops into one compute pass and submits once. Nothing is
//! allocated or compiled per execution. [`Plan::execute_debug`] instead runs op by op and reads back what each
//! wrote.

use std::sync::Arc;

use crate::device::KernelChoice;
use crate::error::{EngineError, Result};
use crate::gpu::{storage_usage, texture_bytes, Gpu, Shader};
use crate::tensor::{Dtype, GpuTensor};

mod execute;
pub use execute::OpOutput;

/// Largest workgroup count per dispatch dimension that WebGPU guarantees.
pub(crate) const MAX_GROUPS_PER_DIM: u32 = 65535;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TensorId(usize);

/// Rows `[row_start, row_start + rows)` of a tensor, bound as a buffer range.
#[derive(Clone, Copy, Debug)]
pub struct View {
    pub id: TensorId,
    pub row_start: usize,
    pub rows: usize,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    Read,
    /// The op writes every element of the view (padding included).
    Write,
    /// The op reads and updates the view (accumulate into it).
    ReadWrite,
}

/// A texture an op binds: rgba32float storage holding a packed matrix (`kernels::pack`).
#[derive(Clone, Debug)]
pub enum TextureRef {
    /// One of the plan's scratch textures, sized for its largest use ([`PlanBuilder::scratch_texels`]). Each
    /// serves every op of the plan: an op packs into it right before the op that reads it, and ops run in
    /// order.
    Scratch(usize),
    /// A packing of a constant tensor ([`PlanBuilder::constant`]), made the first time a plan binds it and
    /// kept by the [`Gpu`] while the tensor lives.
    Kept(TensorId, Arc<dyn KeptTexture>),
    /// A texture owned elsewhere.
    External(Arc<wgpu::Texture>),
}

/// How a kernel packs a constant tensor into a texture that the [`Gpu`] keeps with the tensor
/// (`kernels::pack::KeptPacking`): the plan has it made the first time it binds it, without knowing how.
pub trait KeptTexture: std::fmt::Debug + Send + Sync {
    /// Tells this packing from the tensor's others.
    fn key(&self) -> u64;
    /// Packs `tensor` (named `name`) into a new texture.
    fn make(&self, gpu: &Gpu, name: &str, tensor: &GpuTensor) -> Result<Arc<wgpu::Texture>>;
}

/// One kernel dispatch. Its params are bound at binding 0 as a uniform; `bindings` follow from binding 1,
/// then `textures`.
pub struct Op {
    pub label: String,
    pub shader: &'static Shader,
    pub entry: &'static str,
    /// Uniform contents as 32-bit words: the kernel's `Params` struct cast with bytemuck (`kernels::params!`).
    pub params: Vec<u32>,
    pub bindings: Vec<(View, Access)>,
    pub textures: Vec<(TextureRef, Access)>,
    pub workgroups: [u32; 3],
    /// Values of the shader's override constants (`override NAME: T;`) this op's pipeline is compiled with:
    /// a kernel specialised to its op's shape (`device::fixed_shapes`), else none.
    pub constants: Vec<(&'static str, f64)>,
    /// Multiply-adds of the op's arithmetic (matmuls, attention products, convolutions); 0 for ops whose
    /// work is linear in their data (norms, encodings, resizes, elementwise maps).
    pub multiply_adds: u64,
}

/// Workgroup grid for `groups` groups: WebGPU caps each dimension at 65535, so large counts spill into y.
/// Kernels recover the flat group index as `wid.x + wid.y * nwg.x` and skip indices past the end.
pub fn grid(groups: usize) -> [u32; 3] {
    let groups = groups.max(1) as u32;
    if groups <= MAX_GROUPS_PER_DIM {
        [groups, 1, 1]
    } else {
        let y = groups.div_ceil(MAX_GROUPS_PER_DIM);
        [groups.div_ceil(y), y, 1]
    }
}

#[derive(Clone, Debug)]
enum Storage {
    /// Lives between its first and last use; shares pooled buffers with other transients.
    Transient,
    /// Written by the host before execution; has its own buffer.
    Input,
    /// Read by the host after execution; has its own buffer.
    Output,
    /// Owned elsewhere.
    External(GpuTensor),
    /// Owned elsewhere and never written while it lives (a model weight, a scene's cached tensor), so
    /// packings of it can be kept.
    Constant(GpuTensor),
}

#[derive(Clone, Debug)]
struct TensorInfo {
    name: String,
    rows: usize,
    cols: usize,
    /// F32 for everything the plan allocates; externals (weights) may be F16.
    dtype: Dtype,
    storage: Storage,
}

impl TensorInfo {
    fn row_bytes(&self) -> u64 {
        self.dtype.row_bytes(self.cols) as u64
    }
    fn bytes(&self) -> u64 {
        (self.rows as u64).saturating_mul(self.row_bytes())
    }
}

#[derive(Default)]
pub struct PlanBuilder {
    tensors: Vec<TensorInfo>,
    ops: Vec<Op>,
    /// Which kernels the wrappers record where there is a choice (set from the [`Gpu`] by the model graph;
    /// tests set it to check every variant).
    pub kernels: KernelChoice,
    /// Texels of each scratch texture: the largest that any op asked for.
    scratch_texels: Vec<usize>,
    /// The first tensor too large for the kernels' u32 element offsets: [`build`](Self::build) reports it.
    unindexable: Option<(String, u64)>,
}

impl PlanBuilder {
    pub fn new() -> Self {
        Self::default()
    }

    fn add(&mut self, name: &str, rows: usize, cols: usize, dtype: Dtype, storage: Storage) -> TensorId {
        let info = TensorInfo { name: name.to_string(), rows, cols, dtype, storage };
        if rows.saturating_mul(dtype.ld(cols)) > u32::MAX as usize && self.unindexable.is_none() {
            self.unindexable = Some((info.name.clone(), info.bytes()));
        }
        self.tensors.push(info);
        TensorId(self.tensors.len() - 1)
    }

    /// An intermediate tensor; its buffer is shared with tensors whose lifetimes do not overlap.
    pub fn transient(&mut self, name: &str, rows: usize, cols: usize) -> TensorId {
        self.add(name, rows, cols, Dtype::F32, Storage::Transient)
    }
    pub fn input(&mut self, name: &str, rows: usize, cols: usize) -> TensorId {
        self.add(name, rows, cols, Dtype::F32, Storage::Input)
    }
    pub fn output(&mut self, name: &str, rows: usize, cols: usize) -> TensorId {
        self.add(name, rows, cols, Dtype::F32, Storage::Output)
    }
    pub fn external(&mut self, name: &str, tensor: &GpuTensor) -> TensorId {
        self.add(name, tensor.rows, tensor.cols, tensor.dtype, Storage::External(tensor.clone()))
    }
    /// An external tensor that nothing writes while it lives: a model weight, or a scene's cached tensor
    /// (keys and values). Its packings ([`TextureRef::Kept`]) are made once and kept with it.
    pub fn constant(&mut self, name: &str, tensor: &GpuTensor) -> TensorId {
        self.add(name, tensor.rows, tensor.cols, tensor.dtype, Storage::Constant(tensor.clone()))
    }
    /// Makes an output a transient: for an output that only a later op of the plan reads (a render's readout
    /// reads the region out of it), so that it shares the pooled buffers.
    pub fn make_transient(&mut self, id: TensorId) {
        let storage = &mut self.tensors[id.0].storage;
        assert!(matches!(storage, Storage::Output), "only outputs become transients");
        *storage = Storage::Transient;
    }
    pub fn is_constant(&self, id: TensorId) -> bool {
        matches!(self.tensors[id.0].storage, Storage::Constant(_))
    }

    pub fn rows(&self, id: TensorId) -> usize {
        self.tensors[id.0].rows
    }
    pub fn cols(&self, id: TensorId) -> usize {
        self.tensors[id.0].cols
    }
    /// Row stride in elements (floats, or halves for an F16 tensor).
    pub fn ld(&self, id: TensorId) -> usize {
        let t = &self.tensors[id.0];
        t.dtype.ld(t.cols)
    }
    pub fn dtype(&self, id: TensorId) -> Dtype {
        self.tensors[id.0].dtype
    }
    pub fn name(&self, id: TensorId) -> &str {
        &self.tensors[id.0].name
    }

    /// The whole tensor.
    pub fn all(&self, id: TensorId) -> View {
        View { id, row_start: 0, rows: self.rows(id) }
    }
    /// Rows `[row_start, row_start + rows)` of a tensor.
    pub fn rows_of(&self, id: TensorId, row_start: usize, rows: usize) -> View {
        assert!(row_start + rows <= self.rows(id), "view past the end of {}", self.name(id));
        View { id, row_start, rows }
    }

    /// Whether a tensor of the plan is too large to index; kernel wrappers record nothing more then, and
    /// [`build`](Self::build) fails with [`EngineError::TooLarge`].
    pub fn failed(&self) -> bool {
        self.unindexable.is_some()
    }

    /// Makes scratch texture `slot` ([`TextureRef::Scratch`]) hold at least `texels` texels.
    pub fn scratch_texels(&mut self, slot: usize, texels: usize) {
        if self.scratch_texels.len() <= slot {
            self.scratch_texels.resize(slot + 1, 0);
        }
        self.scratch_texels[slot] = self.scratch_texels[slot].max(texels);
    }

    pub fn push(&mut self, op: Op) {
        self.ops.push(op);
    }

    /// Records the ops recorded so far with shader `from` on `to` instead; returns how many. How the kernel tests
    /// check that they would catch a broken kernel (a shader with a wrong index or a skipped tile must fail them).
    #[doc(hidden)]
    pub fn substitute_shader(&mut self, from: &'static Shader, to: &'static Shader) -> usize {
        let ops = self.ops.iter_mut().filter(|op| std::ptr::eq(op.shader, from));
        ops.map(|op| op.shader = to).count()
    }

    /// The kernel of each op recorded so far, as `shader.entry` (what profiles name them).
    pub fn op_kernels(&self) -> impl Iterator<Item = String> + '_ {
        self.ops.iter().map(|op| format!("{}.{}", op.shader.name, op.entry))
    }

    /// Multiply-adds of the ops recorded so far.
    pub fn multiply_adds(&self) -> u64 {
        self.ops.iter().map(|op| op.multiply_adds).sum()
    }

    /// The pipelines the ops recorded so far run: shader, entry point, override constants (repeats included).
    pub fn pipelines(&self) -> impl Iterator<Item = (&'static Shader, &'static str, &[(&'static str, f64)])> {
        self.ops.iter().map(|op| (op.shader, op.entry, op.constants.as_slice()))
    }

    /// Bytes the plan would allocate when built (pooled intermediates, inputs, outputs, scratch textures; the
    /// params aside), without building it: to size a render before committing memory to it.
    pub fn planned_bytes(&self) -> u64 {
        let (_, _, slot_bytes) = pool(&self.tensors, &self.ops);
        let own = self.tensors.iter().filter(|t| matches!(t.storage, Storage::Input | Storage::Output));
        let texels: usize = self.scratch_texels.iter().sum();
        slot_bytes.iter().sum::<u64>() + own.map(TensorInfo::bytes).sum::<u64>() + texels as u64 * 16
    }

    /// Bytes of the largest tensor the plan binds (what [`Gpu::check_binding_size`] must accept).
    pub fn largest_tensor_bytes(&self) -> u64 {
        self.tensors.iter().map(TensorInfo::bytes).max().unwrap_or(0)
    }

    pub fn build(mut self, gpu: &Gpu) -> Result<Plan> {
        if let Some((what, bytes)) = self.unindexable.take() {
            return Err(EngineError::TooLarge { what, bytes, max: gpu.max_buffer_bytes });
        }
        gpu.compile_pipelines(self.pipelines());
        let PlanBuilder { tensors, ops, scratch_texels, .. } = self;
        let storage_align = gpu.limits.min_storage_buffer_offset_alignment as u64;
        let uniform_align = gpu.limits.min_uniform_buffer_offset_alignment as u64;

        let (live, slot_of, slot_bytes) = pool(&tensors, &ops);

        for (t, info) in tensors.iter().enumerate() {
            gpu.check_binding_size(&info.name, info.bytes())?;
            if matches!(info.storage, Storage::Transient) && live[t].is_none() {
                return Err(EngineError::Bug(format!("plan: tensor {} is never used", info.name)));
            }
        }
        let slot_buffers: Vec<Arc<wgpu::Buffer>> = slot_bytes
            .iter()
            .enumerate()
            .map(|(s, &bytes)| Arc::new(gpu.create_buffer(&format!("pool{s}"), bytes, storage_usage())))
            .collect();
        let mut peak_bytes: u64 = slot_bytes.iter().sum();
        let mut buffers: Vec<Arc<wgpu::Buffer>> = Vec::with_capacity(tensors.len());
        for (t, info) in tensors.iter().enumerate() {
            buffers.push(match &info.storage {
                Storage::Transient => slot_buffers[slot_of[t].expect("transient without slot")].clone(),
                Storage::Input | Storage::Output => {
                    peak_bytes += info.bytes();
                    Arc::new(gpu.create_buffer(&info.name, info.bytes(), storage_usage()))
                }
                Storage::External(tensor) | Storage::Constant(tensor) => tensor.buffer.clone(),
            });
        }

        // All params in one uniform buffer, one aligned block per op.
        let block = |words: usize| ((words * 4) as u64).max(16).div_ceil(uniform_align) * uniform_align;
        let uniform_bytes: u64 = ops.iter().map(|op| block(op.params.len())).sum();
        let uniforms =
            gpu.create_buffer("params", uniform_bytes, wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST);
        peak_bytes += uniform_bytes;
        let mut staged = vec![0u8; uniform_bytes as usize];
        let mut offsets = Vec::with_capacity(ops.len());
        let mut offset = 0u64;
        for op in &ops {
            let bytes: &[u8] = bytemuck::cast_slice(&op.params);
            staged[offset as usize..offset as usize + bytes.len()].copy_from_slice(bytes);
            offsets.push(offset);
            offset += block(op.params.len());
        }
        gpu.queue.write_buffer(&uniforms, 0, &staged);

        // Textures: the scratch ones, and the kept packings of constants (made on first use, kept by the Gpu).
        let scratch = scratch_texels
            .iter()
            .enumerate()
            .map(|(slot, &texels)| gpu.create_texture(&format!("scratch{slot}"), texels).map(Arc::new))
            .collect::<Result<Vec<_>>>()?;
        peak_bytes += scratch.iter().map(|t| texture_bytes(t)).sum::<u64>();
        let mut textures: Vec<Arc<wgpu::Texture>> = Vec::new();
        let mut views: Vec<Vec<wgpu::TextureView>> = Vec::with_capacity(ops.len());
        for op in &ops {
            let mut op_views = Vec::with_capacity(op.textures.len());
            for (texture, _) in &op.textures {
                let texture = match texture {
                    TextureRef::Scratch(slot) => scratch[*slot].clone(),
                    TextureRef::Kept(id, kept) => match &tensors[id.0].storage {
                        Storage::Constant(tensor) => {
                            gpu.kept_texture(tensor, kept.key(), || kept.make(gpu, &tensors[id.0].name, tensor))?
                        }
                        _ => panic!("op {}: only constant tensors have kept packings", op.label),
                    },
                    TextureRef::External(texture) => texture.clone(),
                };
                op_views.push(texture.create_view(&Default::default()));
                textures.push(texture);
            }
            views.push(op_views);
        }

        let mut planned = Vec::with_capacity(ops.len());
        for ((op, &param_offset), op_views) in ops.iter().zip(&offsets).zip(&views) {
            let pipeline = gpu.pipeline(op.shader, op.entry, &op.constants);
            let param_size = ((op.params.len() * 4) as u64).max(16).div_ceil(16) * 16;
            let mut entries = vec![wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: &uniforms,
                    offset: param_offset,
                    size: wgpu::BufferSize::new(param_size),
                }),
            }];
            for (b, (view, _)) in op.bindings.iter().enumerate() {
                let info = &tensors[view.id.0];
                let row_bytes = info.row_bytes();
                let offset = view.row_start as u64 * row_bytes;
                if !offset.is_multiple_of(storage_align) {
                    return Err(EngineError::Bug(format!(
                        "plan: op {} binds {} at byte offset {offset}, not a multiple of {storage_align}",
                        op.label, info.name
                    )));
                }
                entries.push(wgpu::BindGroupEntry {
                    binding: b as u32 + 1,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: &buffers[view.id.0],
                        offset,
                        size: wgpu::BufferSize::new((view.rows as u64 * row_bytes).max(16)),
                    }),
                });
            }
            for (t, view) in op_views.iter().enumerate() {
                entries.push(wgpu::BindGroupEntry {
                    binding: (1 + op.bindings.len() + t) as u32,
                    resource: wgpu::BindingResource::TextureView(view),
                });
            }
            let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(&op.label),
                layout: &pipeline.get_bind_group_layout(0),
                entries: &entries,
            });
            let written = op.bindings.iter().filter(|(_, a)| *a != Access::Read).map(|(v, _)| *v).collect();
            planned.push(PlannedOp {
                label: op.label.clone(),
                shader: op.shader.name,
                entry: op.entry,
                pipeline,
                bind_group,
                workgroups: op.workgroups,
                written,
            });
        }

        let infos = tensors.iter().map(|t| (t.name.clone(), t.rows, t.cols, t.dtype)).collect();
        let multiply_adds = ops.iter().map(|op| op.multiply_adds).sum();
        Ok(Plan { ops: planned, buffers, infos, peak_bytes, multiply_adds, _uniforms: uniforms, _textures: textures })
    }
}

/// Pools the transients of `ops`: walks the ops in order, gives each tensor born at op i the best-fitting free
/// slot (growing the largest free one if none fits), and frees tensors after their last op. Returns each
/// tensor's liveness (first and last op that binds it), each transient's slot and each slot's bytes.
#[allow(clippy::type_complexity)]
fn pool(tensors: &[TensorInfo], ops: &[Op]) -> (Vec<Option<(usize, usize)>>, Vec<Option<usize>>, Vec<u64>) {
    // Liveness of each transient: first and last op that binds it.
    let mut live: Vec<Option<(usize, usize)>> = vec![None; tensors.len()];
    for (i, op) in ops.iter().enumerate() {
        for (view, _) in &op.bindings {
            let span = live[view.id.0].get_or_insert((i, i));
            span.1 = i;
        }
    }

    let mut slot_of: Vec<Option<usize>> = vec![None; tensors.len()];
    let mut slot_bytes: Vec<u64> = Vec::new();
    let mut slot_free: Vec<bool> = Vec::new();
    for i in 0..ops.len() {
        for (t, info) in tensors.iter().enumerate() {
            if !matches!(info.storage, Storage::Transient) || live[t].map(|l| l.0) != Some(i) {
                continue;
            }
            let need = info.bytes();
            let free = (0..slot_bytes.len()).filter(|&s| slot_free[s]);
            let best_fit = free.clone().filter(|&s| slot_bytes[s] >= need).min_by_key(|&s| slot_bytes[s]);
            let slot = match best_fit.or_else(|| free.max_by_key(|&s| slot_bytes[s])) {
                Some(s) => s,
                None => {
                    slot_bytes.push(0);
                    slot_free.push(true);
                    slot_bytes.len() - 1
                }
            };
            slot_bytes[slot] = slot_bytes[slot].max(need);
            slot_free[slot] = false;
            slot_of[t] = Some(slot);
        }
        for (t, slot) in slot_of.iter().enumerate() {
            if let (Some(s), Some((_, last))) = (slot, live[t]) {
                if last == i {
                    slot_free[*s] = true;
                }
            }
        }
    }
    (live, slot_of, slot_bytes)
}

struct PlannedOp {
    label: String,
    shader: &'static str,
    entry: &'static str,
    pipeline: Arc<wgpu::ComputePipeline>,
    bind_group: wgpu::BindGroup,
    workgroups: [u32; 3],
    written: Vec<View>,
}

/// A built plan: buffers allocated, bind groups made, ready to execute any number of times.
pub struct Plan {
    ops: Vec<PlannedOp>,
    buffers: Vec<Arc<wgpu::Buffer>>,
    infos: Vec<(String, usize, usize, Dtype)>,
    peak_bytes: u64,
    multiply_adds: u64,
    _uniforms: wgpu::Buffer,
    _textures: Vec<Arc<wgpu::Texture>>,
}

impl Plan {
    /// Bytes of GPU memory the plan allocated itself (pooled intermediates, inputs, outputs, params);
    /// weights and scene caches it only binds are not counted.
    pub fn peak_bytes(&self) -> u64 {
        self.peak_bytes
    }

    pub fn dispatch_count(&self) -> usize {
        self.ops.len()
    }

    /// Multiply-adds of one execution: the sum of its ops' [`Op::multiply_adds`].
    pub fn multiply_adds(&self) -> u64 {
        self.multiply_adds
    }

    pub fn op_labels(&self) -> impl Iterator<Item = &str> {
        self.ops.iter().map(|o| o.label.as_str())
    }

    /// The buffer a tensor lives in (from its first byte).
    pub(crate) fn buffer(&self, id: TensorId) -> &wgpu::Buffer {
        &self.buffers[id.0]
    }

    /// Bytes of a tensor (rows padded).
    pub(crate) fn tensor_bytes(&self, id: TensorId) -> u64 {
        let (_, rows, cols, dtype) = self.infos[id.0];
        (rows * dtype.row_bytes(cols)) as u64
    }

    /// The buffer of an input or output tensor, as a [`GpuTensor`] the host can write or read.
    pub fn tensor(&self, id: TensorId) -> GpuTensor {
        let (_, rows, cols, dtype) = self.infos[id.0];
        GpuTensor { buffer: self.buffers[id.0].clone(), rows, cols, dtype }
    }
}
