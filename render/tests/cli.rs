//! The `render` command: several seeds and scenes in one run, one report, and bad options
//! refused with a message.

use std::path::Path;
use std::process::Command;

fn render(out: &Path, args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_render"))
        .args([
            "--time", "0", "--spp", "2", "--width", "16", "--height", "12",
        ])
        .args(["--peer", "none", "--out"])
        .arg(out)
        .args(args)
        .output()
        .expect("the render binary runs")
}

/// The methods of a report's table rows, in order.
fn method_rows(report: &str) -> Vec<&str> {
    report
        .lines()
        .filter(|l| l.starts_with("| unguided") || l.starts_with("| guided"))
        .map(|l| l.split('|').nth(1).unwrap().trim())
        .collect()
}

#[test]
fn several_seeds_write_every_image_and_one_summary() {
    let out = std::env::temp_dir().join(format!("sdguide-cli-seeds-{}", std::process::id()));
    let run = render(
        &out,
        &[
            "--scene", "covered", "--seeds", "2", "--seed", "5", "--rule", "l2m",
        ],
    );
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("seeds 5–6"), "{report}");
    assert!(
        report.contains("Seed 5:") && report.contains("Seed 6:"),
        "{report}"
    );
    assert!(report.contains("## Summary over 2 seeds"), "{report}");
    assert!(report.contains("| covered | guided-l2m |"), "{report}");
    // Every table has the column of the images combined with their training passes.
    assert!(report.contains("| with training passes |"), "{report}");
    for seed in [5, 6] {
        for method in ["unguided", "guided-l2m"] {
            let stem = format!("covered-{method}-seed{seed}");
            assert!(out.join(format!("{stem}.exr")).is_file(), "{stem}");
        }
        assert!(
            out.join(format!("covered-guided-l2m-seed{seed}.sdgc"))
                .is_file()
        );
    }
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn without_roulette_every_method_runs_beside_its_unguided_baseline() {
    let out = std::env::temp_dir().join(format!("sdguide-cli-rrs-{}", std::process::id()));
    let run = render(&out, &["--scene", "door", "--rule", "l2", "--rrs", "none"]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    // Unguided with classic roulette stays the first row, the baseline of the ratios.
    let rows = method_rows(&report);
    assert_eq!(
        rows,
        ["unguided", "unguided-no-rr", "guided-l2-no-rr"],
        "{report}"
    );
    assert!(
        report.contains("| per sample vs unguided, same roulette |"),
        "{report}"
    );
    for method in ["unguided", "unguided-no-rr", "guided-l2-no-rr"] {
        assert!(out.join(format!("door-{method}.exr")).is_file(), "{method}");
    }
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn without_rule_and_roulette_the_recommended_comparison_runs() {
    let out = std::env::temp_dir().join(format!("sdguide-cli-default-{}", std::process::id()));
    let run = render(&out, &["--scene", "door"]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    let expected = ["unguided", "unguided-ears", "guided-l2m-ears"];
    assert_eq!(method_rows(&report), expected, "{report}");
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn bad_options_are_refused_with_a_message() {
    let out = std::env::temp_dir().join(format!("sdguide-cli-bad-{}", std::process::id()));
    for args in [
        &["--seeds", "0"][..],
        &["--scene", "nowhere"],
        &["--rule", "l3"],
        &["--rrs", "never"],
        &["--scene", "all", "--probe", "x.sdgc"],
        &["--scene", "all", "--cache", "x.sdgc"],
    ] {
        let run = render(&out, args);
        assert!(!run.status.success(), "{args:?}");
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(stderr.starts_with("render: "), "{args:?}: {stderr}");
    }
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn training_and_rendering_give_the_same_bytes_whatever_the_thread_count() {
    // At a fixed sample count, every pixel's samples and every recorded sample are the
    // same, and the field's sums are exact: the caches are byte-identical, and so are the
    // images (the PNGs; the EXRs' compression runs in parallel and orders its blocks as
    // they finish).
    let files = [
        "door-guided-l2m-ears.sdgc",
        "door-unguided-ears.sdgc",
        "door-guided-l2m-ears.png",
        "door-unguided.png",
    ];
    let runs: Vec<Vec<Vec<u8>>> = ["1", "2", "5"]
        .iter()
        .map(|threads| {
            let out = std::env::temp_dir().join(format!(
                "sdguide-cli-threads-{threads}-{}",
                std::process::id()
            ));
            let run = Command::new(env!("CARGO_BIN_EXE_render"))
                .args([
                    "--scene", "door", "--time", "0", "--spp", "4", "--width", "48",
                ])
                .args([
                    "--height",
                    "36",
                    "--peer",
                    "none",
                    "--threads",
                    threads,
                    "--out",
                ])
                .arg(&out)
                .output()
                .expect("the render binary runs");
            assert!(
                run.status.success(),
                "{}",
                String::from_utf8_lossy(&run.stderr)
            );
            let bytes = files
                .iter()
                .map(|f| std::fs::read(out.join(f)).unwrap())
                .collect();
            std::fs::remove_dir_all(&out).unwrap();
            bytes
        })
        .collect();
    for (threads, run) in ["2", "5"].iter().zip(&runs[1..]) {
        for (f, (a, b)) in files.iter().zip(runs[0].iter().zip(run)) {
            assert!(a == b, "{f}: 1 thread and {threads} differ");
        }
    }
}
