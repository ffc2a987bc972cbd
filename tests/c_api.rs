//! The C ABI as C and C++ programs use it: `tests/c/consumer.c` (gcc `-std=c99 -Wall -Wextra
//! -Werror -pedantic`) and `tests/c/consumer.cpp` (g++ `-std=c++17 -Wall -Wextra -Werror
//! -pedantic`) are compiled against `include/ndfmap.h`, linked once against `libndfmap.so` and
//! once against `libndfmap.a` (both built beside this test binary, in the profile's `deps/`
//! folder, because the library's crate types include `cdylib` and `staticlib`), run, and their
//! output compared line by line with what the Rust API gives for the same map. The C consumer
//! and the C++ one also run under valgrind (no invalid access, no definite or indirect leak)
//! when it is installed; the C sample (`samples/c/`) is built with the flags of `ndfmap.pc` and
//! run; and the shared library exports exactly the functions the header declares.
//!
//! A missing gcc, g++ or valgrind skips the part that needs it, except under CI (`CI` set),
//! where `scripts/test` installs them and their absence is a failure.

use ndfmap::bake::{Bake, BakeOptions, Method};
use ndfmap::em::AlignmentForm;
use ndfmap::format::Format;
use ndfmap::format::ValueRange;
use ndfmap::glsl::{ShaderOptions, ShaderSpec, Stage, source_for};
use ndfmap::ingest::Samples;
use ndfmap::methods::bake_with;
use ndfmap::{IngestOptions, NormalMap};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Side of the test map (as `SIZE` in consumer.c and consumer.cpp).
const SIZE: u32 = 16;

/// What a Rust static library needs from the system on Linux (`rustc --print
/// native-static-libs`), as README's "Using ndfmap from C/C++" lists it.
const NATIVE_STATIC_LIBS: [&str; 7] = [
    "-lgcc_s",
    "-lutil",
    "-lrt",
    "-lpthread",
    "-lm",
    "-ldl",
    "-lc",
];

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The folder holding `libndfmap.so` and `libndfmap.a` of this build.
fn lib_dir() -> PathBuf {
    let dir = std::env::current_exe()
        .unwrap()
        .parent()
        .unwrap()
        .to_path_buf();
    for lib in ["libndfmap.so", "libndfmap.a"] {
        assert!(
            dir.join(lib).is_file(),
            "{lib} is not in {} (the lib target's crate types build it)",
            dir.display()
        );
    }
    dir
}

/// Whether `tool` runs; under CI a missing tool is a failure, elsewhere a skip.
fn have(tool: &str) -> bool {
    let ok = Command::new(tool)
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        assert!(
            std::env::var_os("CI").is_none(),
            "{tool} is missing (scripts/test installs it)"
        );
        eprintln!("skipped: {tool} is not installed");
    }
    ok
}

/// How a consumer links the library.
#[derive(Clone, Copy, Debug)]
enum Link {
    Shared,
    Static,
}

/// Compiles `source` with `compiler` and `flags` against the header and the library, into `out`.
fn build(compiler: &str, flags: &[&str], source: &Path, link: Link, out: &Path) {
    let lib = lib_dir();
    let mut cmd = Command::new(compiler);
    cmd.args(flags)
        .arg("-I")
        .arg(root().join("include"))
        .arg(source)
        .arg("-o")
        .arg(out);
    match link {
        Link::Shared => {
            cmd.arg("-L")
                .arg(&lib)
                .arg("-lndfmap")
                .arg("-lm")
                .arg(format!("-Wl,-rpath,{}", lib.display()));
        }
        Link::Static => {
            cmd.arg(lib.join("libndfmap.a")).args(NATIVE_STATIC_LIBS);
        }
    }
    let result = cmd.output().unwrap();
    assert!(
        result.status.success(),
        "{compiler} {} ({link:?}) failed:\n{}",
        source.display(),
        String::from_utf8_lossy(&result.stderr)
    );
}

/// Runs `program` with `args` (under `wrapper` if given) and returns its standard output.
fn run(wrapper: &[&str], program: &Path, args: &[&Path]) -> String {
    let mut cmd = match wrapper.split_first() {
        Some((first, rest)) => {
            let mut c = Command::new(first);
            c.args(rest).arg(program);
            c
        }
        None => Command::new(program),
    };
    // `cargo test` puts `target/<profile>` on LD_LIBRARY_PATH, and the dynamic loader searches
    // it before the program's RUNPATH: a `libndfmap.so` left there by an earlier `cargo build`
    // (cargo refreshes that copy only when it builds the library target itself, not for tests)
    // would be loaded instead of this build's. The programs find their library by RUNPATH.
    cmd.env_remove("LD_LIBRARY_PATH");
    let result = cmd.args(args).output().unwrap();
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(
        result.status.success(),
        "{} failed ({}):\n{stderr}",
        program.display(),
        result.status
    );
    String::from_utf8(result.stdout).unwrap()
}

/// The test map's pixels: the integer formulas of consumer.c.
fn pixels() -> Vec<u8> {
    (0..SIZE * SIZE)
        .flat_map(|i| {
            let (x, y) = (i % SIZE, i / SIZE);
            [
                (x * 37 + y * 11) % 256,
                (x * 13 + y * 29 + 64) % 256,
                200 + (x + y) % 56,
            ]
            .map(|v| v as u8)
        })
        .collect()
}

/// Writes the test map as a PNG file into `dir`.
fn png(dir: &Path) -> PathBuf {
    let path = dir.join("map.png");
    image::RgbImage::from_raw(SIZE, SIZE, pixels())
        .unwrap()
        .save(&path)
        .unwrap();
    path
}

/// 64-bit FNV-1a of `bytes` (as consumer.c computes it).
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(14_695_981_039_346_656_037, |h, &b| {
        (h ^ b as u64).wrapping_mul(1_099_511_628_211)
    })
}

const FORMATS: [Format; 4] = [Format::F32, Format::F16, Format::Unorm16, Format::Unorm8];

/// The `pack` line consumer.c prints for texture `t`, level `k`, `format`.
fn pack_line(bake: &Bake, t: usize, k: usize, format: Format) -> String {
    if ndfmap::pack::check(bake, t, format).is_err() {
        return format!("pack {t} {k} {format} unsupported");
    }
    let mut buf = vec![0u8; ndfmap::pack::packed_len(bake, k, format)];
    let n = ndfmap::pack::pack_level(bake, t, k, format, &mut buf).unwrap();
    format!("pack {t} {k} {format} {n} {:016x}", fnv1a(&buf))
}

/// The bakes consumer.c makes, with the Rust API.
fn bakes() -> Vec<Bake> {
    let map = NormalMap::from_samples(
        "pixels",
        SIZE,
        SIZE,
        3,
        Samples::U8(&pixels()),
        &IngestOptions::default(),
    )
    .unwrap();
    let mut bakes: Vec<Bake> = Method::ALL
        .into_iter()
        .map(|m| {
            let options = BakeOptions {
                lobes: 2,
                align: (m == Method::Vmf).then_some(AlignmentForm::Appendix.default_strength()),
                ..BakeOptions::default()
            };
            bake_with(&map, m, &options).unwrap()
        })
        .collect();
    // consumer.c's PBR bake: anisotropic, with its roughness map.
    let roughness = (0..SIZE * SIZE)
        .map(|i| (((i % SIZE) * 3 + i / SIZE) % 8) as f32 / 8.0)
        .collect();
    let maps = ndfmap::pbr::PbrMaps {
        roughness: Some(roughness),
        ..Default::default()
    };
    let options = ndfmap::bake::PbrOptions {
        anisotropic: true,
        ..Default::default()
    };
    bakes.push(ndfmap::pbr::bake_with_maps(&map, &options, Some(&maps)).unwrap());
    bakes
}

/// What consumer.c prints, computed with the Rust API.
fn expected_c_output() -> String {
    let mut out = vec![
        format!("version {}", env!("CARGO_PKG_VERSION")),
        format!("map {SIZE}x{SIZE}"),
    ];
    for b in bakes() {
        out.push(format!(
            "bake {} lobes {} levels {} textures {}",
            b.method,
            b.lobes,
            b.level_count(),
            b.textures.len()
        ));
        for (k, (w, h)) in b.sizes.iter().enumerate() {
            out.push(format!("level {k} {w}x{h}"));
        }
        for (t, texture) in b.textures.iter().enumerate() {
            let mut line = format!("texture {t} {}", texture.name);
            for (meaning, range) in texture.channels.iter().zip(texture.ranges) {
                let code = match range {
                    ValueRange::Unit => 0,
                    ValueRange::Signed => 1,
                    ValueRange::Any => 2,
                };
                line += &format!(" {meaning}:{code}");
            }
            out.push(line);
            for k in 0..b.level_count() {
                for format in FORMATS {
                    out.push(pack_line(&b, t, k, format));
                }
            }
        }
    }
    let vmf = bakes()
        .into_iter()
        .find(|b| b.method == Method::Vmf)
        .unwrap();
    let spec = ShaderSpec {
        format: Format::F16,
        ..ShaderSpec::of(&vmf)
    };
    for (i, stage) in [Stage::Vertex, Stage::Fragment].into_iter().enumerate() {
        let mut source = source_for(&spec, stage, &ShaderOptions::default())
            .unwrap()
            .into_bytes();
        source.push(0);
        out.push(format!(
            "shader {i} {} {:016x}",
            source.len(),
            fnv1a(&source)
        ));
    }
    out.push("bad input checked".into());
    out.join("\n") + "\n"
}

/// What consumer.cpp prints: the vMF bake's levels packed as f16.
fn expected_cpp_output() -> String {
    let vmf = bakes()
        .into_iter()
        .find(|b| b.method == Method::Vmf)
        .unwrap();
    let mut out = String::new();
    for t in 0..vmf.textures.len() {
        for k in 0..vmf.level_count() {
            out += &pack_line(&vmf, t, k, Format::F16);
            out.push('\n');
        }
    }
    out
}

/// Asserts `got` equals `want`, naming the first line that differs.
fn same_lines(got: &str, want: &str, what: &str) {
    if got != want {
        let (g, w): (Vec<_>, Vec<_>) = (got.lines().collect(), want.lines().collect());
        let i = g
            .iter()
            .zip(&w)
            .position(|(a, b)| a != b)
            .unwrap_or(g.len().min(w.len()));
        panic!(
            "{what}: line {} differs from the Rust API's:\n  C:    {:?}\n  Rust: {:?}\n({} and {} lines)",
            i + 1,
            g.get(i),
            w.get(i),
            g.len(),
            w.len()
        );
    }
}

const C_FLAGS: [&str; 5] = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"];
const CPP_FLAGS: [&str; 5] = ["-std=c++17", "-Wall", "-Wextra", "-Werror", "-pedantic"];

#[test]
fn c_consumer_linked_shared_and_static_matches_the_rust_api() {
    if !have("gcc") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let map = png(tmp.path());
    let want = expected_c_output();
    for link in [Link::Shared, Link::Static] {
        let exe = tmp.path().join(format!("consumer-c-{link:?}"));
        build(
            "gcc",
            &C_FLAGS,
            &root().join("tests/c/consumer.c"),
            link,
            &exe,
        );
        let out_dir = tmp.path().join(format!("bake-{link:?}"));
        same_lines(
            &run(&[], &exe, &[&out_dir, &map]),
            &want,
            &format!("consumer.c ({link:?})"),
        );
        // ndf_bake_write wrote the vMF bake as the command line does.
        let manifest: ndfmap::output::Manifest =
            serde_json::from_str(&std::fs::read_to_string(out_dir.join("manifest.json")).unwrap())
                .unwrap();
        assert_eq!(manifest.method, Method::Vmf);
        assert_eq!(manifest.texel_format, Format::F16);
        assert_eq!(manifest.input.path.as_deref(), map.to_str());
        for f in manifest.textures.iter().flat_map(|t| &t.files) {
            assert!(out_dir.join(f).is_file(), "{f}");
        }
    }
}

#[test]
fn cpp_consumer_linked_shared_and_static_matches_the_rust_api() {
    if !have("g++") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let want = expected_cpp_output();
    for link in [Link::Shared, Link::Static] {
        let exe = tmp.path().join(format!("consumer-cpp-{link:?}"));
        build(
            "g++",
            &CPP_FLAGS,
            &root().join("tests/c/consumer.cpp"),
            link,
            &exe,
        );
        same_lines(
            &run(&[], &exe, &[]),
            &want,
            &format!("consumer.cpp ({link:?})"),
        );
    }
}

#[test]
fn consumers_run_clean_under_valgrind() {
    if !(have("valgrind") && have("gcc") && have("g++")) {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let map = png(tmp.path());
    let valgrind = [
        "valgrind",
        "--quiet",
        "--error-exitcode=99",
        "--leak-check=full",
        "--errors-for-leak-kinds=definite,indirect",
    ];
    let c = tmp.path().join("consumer-c");
    build(
        "gcc",
        &C_FLAGS,
        &root().join("tests/c/consumer.c"),
        Link::Shared,
        &c,
    );
    let out = run(&valgrind, &c, &[&tmp.path().join("bake"), &map]);
    same_lines(&out, &expected_c_output(), "consumer.c under valgrind");
    let cpp = tmp.path().join("consumer-cpp");
    build(
        "g++",
        &CPP_FLAGS,
        &root().join("tests/c/consumer.cpp"),
        Link::Static,
        &cpp,
    );
    same_lines(
        &run(&valgrind, &cpp, &[]),
        &expected_cpp_output(),
        "consumer.cpp under valgrind",
    );
}

#[test]
fn sample_builds_with_the_pkg_config_file_and_prints_every_upload() {
    if !(have("gcc") && have("pkg-config") && have("sed")) {
        return;
    }
    // An install tree as scripts/install makes it, with the library of this build.
    let tmp = tempfile::tempdir().unwrap();
    let prefix = tmp.path().join("prefix");
    let lib = prefix.join("lib");
    std::fs::create_dir_all(lib.join("pkgconfig")).unwrap();
    std::fs::create_dir_all(prefix.join("include")).unwrap();
    std::fs::copy(
        root().join("include/ndfmap.h"),
        prefix.join("include/ndfmap.h"),
    )
    .unwrap();
    std::os::unix::fs::symlink(lib_dir().join("libndfmap.so"), lib.join("libndfmap.so")).unwrap();
    // The sed line of scripts/install and ndfmap.pc.in.
    let pc = Command::new("sed")
        .arg("-e")
        .arg(format!("s|@PREFIX@|{}|", prefix.display()))
        .arg("-e")
        .arg(format!("s|@VERSION@|{}|", env!("CARGO_PKG_VERSION")))
        .arg(root().join("ndfmap.pc.in"))
        .output()
        .unwrap();
    assert!(pc.status.success());
    std::fs::write(lib.join("pkgconfig/ndfmap.pc"), pc.stdout).unwrap();
    let pkg_config = |args: &[&str]| {
        let out = Command::new("pkg-config")
            .args(args)
            .arg("ndfmap")
            .env("PKG_CONFIG_PATH", lib.join("pkgconfig"))
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap().trim().to_string()
    };
    assert_eq!(pkg_config(&["--modversion"]), env!("CARGO_PKG_VERSION"));
    let flags = pkg_config(&["--cflags", "--libs"]);

    let exe = tmp.path().join("ndf_upload");
    let result = Command::new("gcc")
        .args(C_FLAGS)
        .arg(root().join("samples/c/ndf_upload.c"))
        .arg("-o")
        .arg(&exe)
        .args(flags.split_whitespace())
        .arg(format!("-Wl,-rpath,{}", lib.display()))
        .arg("-lm")
        .output()
        .unwrap();
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );
    let map = png(tmp.path());
    let out = run(&[], &exe, &[&map]);
    assert!(out.starts_with("// 4 vMF lobes, 5 MIP levels"), "{out}");
    let uploads: Vec<_> = out
        .lines()
        .filter(|l| l.starts_with("glTexImage2D("))
        .collect();
    assert_eq!(uploads.len(), 4 * 5, "{out}");
    assert!(
        uploads[0].contains("GL_RGBA16F, 16, 16, 0, GL_RGBA, GL_HALF_FLOAT")
            && uploads[0].contains("2048 bytes"),
        "{}",
        uploads[0]
    );
    assert!(out.contains("bytes of GLSL 3.30"), "{out}");
    // Without an argument it bakes its own map.
    assert!(run(&[], &exe, &[]).contains("// 4 vMF lobes, 7 MIP levels"));
}

#[test]
fn the_shared_library_exports_exactly_the_functions_the_header_declares() {
    if !have("nm") {
        return;
    }
    let out = Command::new("nm")
        .args(["-D", "--defined-only"])
        .arg(lib_dir().join("libndfmap.so"))
        .output()
        .unwrap();
    assert!(out.status.success());
    let mut exported: Vec<String> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .filter_map(|l| l.split_whitespace().nth(2))
        .filter(|s| !s.starts_with('_'))
        .map(str::to_string)
        .collect();
    exported.sort();
    let header = std::fs::read_to_string(root().join("include/ndfmap.h")).unwrap();
    // Declarations start a line with their return type: `ndf_status ndf_bake_pack(...`.
    let mut declared: Vec<String> = header
        .lines()
        .filter(|l| l.starts_with(|c: char| c.is_ascii_lowercase()) && l.contains('('))
        .filter_map(|l| {
            l.split('(')
                .next()?
                .split([' ', '*'])
                .next_back()
                .map(str::to_string)
        })
        .filter(|name| name.starts_with("ndf_"))
        .collect();
    declared.sort();
    assert!(declared.len() > 30, "{declared:?}");
    assert_eq!(exported, declared);
}
