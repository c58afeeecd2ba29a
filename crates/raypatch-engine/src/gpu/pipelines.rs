//! The Gpu's compute pipelines: compiled once per shader, entry point and override constants, a plan's all at
//! once (a thread per core; in a browser one after another), through the driver's pipeline cache on disk where there is one. Each pipeline has
//! a slot that the first thread to want it compiles into while any other that wants it waits (a model's
//! warm-up, `model.rs`, and the plans of a first encode and render may ask for the same ones at once).

use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};
use web_time::Instant;

use super::{Gpu, Shader};

/// A compiled pipeline's identity: shader, entry point, and its override constants' values (as bits).
type PipelineKey = (&'static str, &'static str, Vec<(&'static str, u64)>);

/// A pipeline, once compiled.
type Slot = Arc<OnceLock<Arc<wgpu::ComputePipeline>>>;

/// Every pipeline asked for, compiled or being compiled.
pub(super) type Pipelines = HashMap<PipelineKey, Slot>;

/// A pipeline as plans ask for it: shader, entry point, override constants.
type Wanted<'a> = (&'static Shader, &'static str, &'a [(&'static str, f64)]);

fn pipeline_key(shader: &Shader, entry: &'static str, constants: &[(&'static str, f64)]) -> PipelineKey {
    (shader.name, entry, constants.iter().map(|&(name, value)| (name, value.to_bits())).collect())
}

impl Gpu {
    /// The compute pipeline of `shader`'s `entry` with its override `constants`, compiled on first use (through
    /// the pipeline cache on disk, where there is one) and cached for the life of the Gpu.
    pub fn pipeline(
        &self,
        shader: &'static Shader,
        entry: &'static str,
        constants: &[(&'static str, f64)],
    ) -> Arc<wgpu::ComputePipeline> {
        let slot = self.slot(pipeline_key(shader, entry, constants));
        slot.get_or_init(|| Arc::new(self.compile(shader, entry, constants))).clone()
    }

    /// The slot of a pipeline, made empty on first ask.
    fn slot(&self, key: PipelineKey) -> Slot {
        self.pipelines.lock().expect("pipeline cache poisoned").entry(key).or_default().clone()
    }

    /// Compiles every pipeline of `wanted` not compiled yet, several at once (one thread per core, up to one
    /// per pipeline): a plan's distinct pipelines before it is built, so that its first run does not compile
    /// them one after another. One that another thread is compiling is waited for, not compiled again.
    pub fn compile_pipelines<'a>(&self, wanted: impl IntoIterator<Item = Wanted<'a>>) {
        let mut missing: Vec<(PipelineKey, Wanted<'a>)> = Vec::new();
        {
            let cache = self.pipelines.lock().expect("pipeline cache poisoned");
            for (shader, entry, constants) in wanted {
                let key = pipeline_key(shader, entry, constants);
                let compiled = cache.get(&key).is_some_and(|slot| slot.get().is_some());
                if !compiled && !missing.iter().any(|m| m.0 == key) {
                    missing.push((key, (shader, entry, constants)));
                }
            }
        }
        // A browser has no threads to spare (and wasm32 none at all): there every pipeline is compiled where it is
        // first asked for.
        if missing.len() < 2 || cfg!(target_family = "wasm") {
            return; // one is compiled where it is first asked for
        }
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).min(missing.len());
        let next = AtomicUsize::new(0);
        std::thread::scope(|scope| {
            for _ in 0..threads {
                scope.spawn(|| loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some((key, (shader, entry, constants))) = missing.get(i) else { break };
                    self.slot(key.clone()).get_or_init(|| Arc::new(self.compile(shader, entry, constants)));
                });
            }
        });
    }

    /// `shader`'s module, made on first use.
    fn module(&self, shader: &'static Shader) -> Arc<wgpu::ShaderModule> {
        if let Some(module) = self.modules.lock().expect("module cache poisoned").get(shader.name) {
            return module.clone();
        }
        let descriptor =
            wgpu::ShaderModuleDescriptor { label: Some(shader.name), source: wgpu::ShaderSource::Wgsl(shader.wgsl()) };
        let module = Arc::new(if shader.features.contains(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX) {
            // SAFETY: the tensor kernels index in range by construction (shaders/coop_tiles.wgsl: the operands are
            // staged with zeros past their edges, every fragment load reads staged memory, every store is checked
            // against out's size; attention_coop.wgsl likewise), and their tests put NaN around the operands and a
            // sentinel around the outputs (tests/kernels, `coop`). Runtime bounds checks cost a GEMM 17-40%
            // (gpuweb #1202) and do not cover the tile a cooperative load reads.
            unsafe { self.device.create_shader_module_trusted(descriptor, wgpu::ShaderRuntimeChecks::unchecked()) }
        } else {
            self.device.create_shader_module(descriptor)
        });
        self.modules.lock().expect("module cache poisoned").entry(shader.name).or_insert(module).clone()
    }

    /// Compiles one pipeline, counted in [`counters`](Self::counters) (the compile time of pipelines compiled at
    /// once adds up: CPU time, not wall time).
    fn compile(
        &self,
        shader: &'static Shader,
        entry: &'static str,
        constants: &[(&'static str, f64)],
    ) -> wgpu::ComputePipeline {
        self.counters.pipelines_compiled.fetch_add(1, Ordering::Relaxed);
        let start = Instant::now();
        let module = self.module(shader);
        let pipeline = self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry),
            layout: None,
            module: &module,
            entry_point: Some(entry),
            compilation_options: wgpu::PipelineCompilationOptions { constants, ..Default::default() },
            cache: self.pipeline_cache.wgpu(),
        });
        let nanos = start.elapsed().as_nanos().try_into().unwrap_or(u64::MAX);
        self.counters.pipeline_compile_nanos.fetch_add(nanos, Ordering::Relaxed);
        self.pipeline_cache.compiled();
        pipeline
    }
}
