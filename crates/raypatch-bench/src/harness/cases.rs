//! The golden cases (assets/golden) and the model files given with `--model`: each measured on its own scene.

use std::path::PathBuf;

use anyhow::{Context, Result};
use raypatch_engine::{Model, Precision};

use super::{scene, Bench, Options, INPUT_SIZE};
use crate::pytorch;
use crate::report::Record;

impl Bench {
    /// Every golden case: errors against PyTorch's float32 output and both float64 references, PSNR where the
    /// scene has ground truth.
    pub(super) fn golden(&self, records: &mut Vec<Record>) -> Result<()> {
        let dir = pytorch::source_file("assets/golden");
        let mut cases: Vec<PathBuf> = std::fs::read_dir(&dir)
            .with_context(|| format!("{}: the golden cases are missing", dir.display()))?
            .map(|e| e.map(|e| e.path()))
            .collect::<std::io::Result<_>>()?;
        cases.retain(|p| p.join("expected.safetensors").exists());
        cases.sort();
        println!("golden cases (assets/golden): errors against PyTorch and the float64 reference");
        for case in cases {
            let name = case.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            let loaded = raypatch_model::load_model(case.join("model.safetensors"))?;
            let scene = raypatch_model::load_scene(case.join("scene.safetensors"))?;
            let truth = raypatch_model::TensorFile::open(&case.join("expected.safetensors"))?.f32("rgb")?.data;
            let model = Model::from_loaded(self.gpu.clone(), &loaded)?;
            let references = self.references(&loaded, &model, &scene.inputs)?;
            let subject = self.subject(
                name,
                "golden",
                &loaded,
                None,
                &model,
                (Precision::F32, None),
                &scene.inputs,
                references.as_ref().map_err(Clone::clone),
            )?;
            records.push(self.measure(&subject, &scene.targets, Some(&truth), false)?);
            if loaded.config.has_depth() {
                records.extend(self.logdepth_skip(&subject, &scene.targets)?);
            }
        }
        Ok(())
    }

    /// Model files given on the command line, on their scene (or a synthetic one).
    pub(super) fn model_files(&self, options: &Options, records: &mut Vec<Record>) -> Result<()> {
        for path in &options.models {
            let loaded = raypatch_model::load_model(path)?;
            let (inputs, targets) = match &options.scene {
                Some(scene) => {
                    let s = raypatch_model::load_scene(scene)?;
                    (s.inputs, s.targets)
                }
                None => scene(1, INPUT_SIZE, 1, (120, 160))?,
            };
            let model = Model::from_loaded(self.gpu.clone(), &loaded)?;
            let file = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
            let references = self.references(&loaded, &model, &inputs)?;
            let name = path.display().to_string();
            let subject = self.subject(
                name,
                "model",
                &loaded,
                Some(&file),
                &model,
                (Precision::F32, None),
                &inputs,
                references.as_ref().map_err(Clone::clone),
            )?;
            records.push(self.measure(&subject, &targets, None, true)?);
        }
        Ok(())
    }
}
