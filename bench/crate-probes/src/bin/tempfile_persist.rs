//! tempfile 3.27 NamedTempFile::persist against canodom's atomic_file::write (#21).
use std::io::Write;
use std::os::unix::fs::PermissionsExt;

fn main() {
    let dir = std::env::temp_dir().join(format!("tf-probe-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let target = dir.join("params.toml");
    // The durable recipe with tempfile: write, fsync file, persist (rename), fsync dir.
    let mut t = tempfile::NamedTempFile::new_in(&dir).unwrap();
    t.write_all(b"x = 1\n").unwrap();
    t.as_file().sync_all().unwrap();
    t.persist(&target).unwrap();
    std::fs::File::open(&dir).unwrap().sync_all().unwrap();
    let mode = std::fs::metadata(&target).unwrap().permissions().mode() & 0o777;
    println!("mode after persist: {mode:o}");
    // A crash between write and rename, three times: what is left behind?
    for _ in 0..3 {
        let t = tempfile::NamedTempFile::new_in(&dir).unwrap();
        std::mem::forget(t);
    }
    let mut names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    names.sort();
    println!("after 3 crashed attempts: {names:?}");
    // A directory squatting the temp name cannot make it fail: names are random.
    std::fs::remove_dir_all(&dir).unwrap();
}
