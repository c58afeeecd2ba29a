#![no_main]
// See raypatch::fuzzing::scene_file.
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    raypatch::fuzzing::scene_file(data);
});
