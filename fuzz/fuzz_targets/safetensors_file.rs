#![no_main]
// See raypatch::fuzzing::safetensors_file.
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    raypatch::fuzzing::safetensors_file(data);
});
