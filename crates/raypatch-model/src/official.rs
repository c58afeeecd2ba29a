//! The official runs of tberriel/RayPatchQuerying (297afbc): each run's model section, as its
//! `runs/<dataset>/<run>/config.yaml` has it, from `assets/official/configs.json`, the one copy that
//! `tools/reference/official_configs.py` reads too. Their state_dict key lists are `assets/official/keys/<run>.txt`.

use serde_json::Value;

const CONFIGS: &str = include_str!("../../../assets/official/configs.json");

/// The official runs: MSN-Easy SRT, RP-SRT k=4, OSRT, RP-OSRT k=8; ScanNet DeFiNe, RP-DeFiNe k=16.
pub const RUNS: [&str; 6] = [
    "srt_MDBN_32",
    "rpsrt_MDBN_4_32",
    "osrt_MDBN_64",
    "rposrt_MDBN_8_64",
    "define_32_stereo_acc",
    "rpdefine_16_32_stereo_acc",
];

/// The model section of the official run `run` (one of [`RUNS`]).
///
/// # Panics
/// When `run` is not one of [`RUNS`].
pub fn config(run: &str) -> Value {
    let all: Value = serde_json::from_str(CONFIGS).expect("assets/official/configs.json is JSON");
    all.get(run).cloned().unwrap_or_else(|| panic!("no official run {run}: the runs are {RUNS:?}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_run_is_there_and_parses() {
        let all: Value = serde_json::from_str(CONFIGS).unwrap();
        assert_eq!(all.as_object().unwrap().len(), RUNS.len());
        for run in RUNS {
            crate::ModelConfig::from_value(run, config(run)).unwrap();
        }
    }
}
