#![no_main]
// See raypatch::fuzzing::checkpoint_file.
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    raypatch::fuzzing::checkpoint_file(data);
});
