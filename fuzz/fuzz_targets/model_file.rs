#![no_main]
// See raypatch::fuzzing::model_file.
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    raypatch::fuzzing::model_file(data);
});
