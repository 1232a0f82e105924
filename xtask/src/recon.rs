//! `cargo xtask bench recon`: the reconstruction accuracy harness.
//!
//! Renders oracle views of real meshes (`../shared/data/meshes`, normalised to the unit
//! cube, faces oriented outwards), reconstructs them with `w3d-recon`, evaluates the result
//! against the original with `w3d-eval`, and writes every run to `target/bench/recon.json`.
//! A full run (no `--meshes` filter) also writes `docs/accuracy.md`.
//!
//! Arguments (after `--`): `--meshes a,b` (file stems), `--cases ortho,persp,presets,
//! concave,stability,robustness` (default all; `robustness`: the cases of `crate::robust`), `--size N` (default 256), `--docs-from-json` (rewrite
//! `docs/accuracy.md` from the last `target/bench/recon.json` without reconstructing),
//! `--texture` (novel-view texture fidelity of reconstructed spot and bob →
//! `target/bench/recon_texture.json`, included in `docs/accuracy.md`).

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;
use std::time::Instant;

use serde_json::{Value, json};
use wonder3d::eval::{EvalOptions, evaluate};
use wonder3d::raster::render_oracle_views;
use wonder3d::recon::{Preset, ReconOptions, reconstruct};
use wonder3d::{Mesh, ViewRig, ViewSet, load_mesh};

use crate::robust;

/// The 14 closed meshes of `../shared/data/meshes` (the ones volume IoU is defined for).
pub(crate) const CLOSED: &[&str] = &[
    "spot.obj",
    "bob_tri.obj",
    "armadillo.obj",
    "cow.obj",
    "cheburashka.obj",
    "fandisk.obj",
    "rocker-arm.obj",
    "torus.obj",
    "boot.obj",
    "hammer.obj",
    "wingnut.obj",
    "plane.obj",
    "koala_low_resolution.obj",
    "horse.ply",
];

/// The open, concave meshes (teacup, teapot; the teacup also turned so that its opening
/// faces the front camera): `(file, turned)`, loaded by [`load_concave`].
pub(crate) const CONCAVE: &[(&str, bool)] = &[("teacup.obj", false), ("teapot.obj", false), ("teacup.obj", true)];

/// The cases of a full run (`--cases` picks some).
const ALL_CASES: &[&str] = &["ortho", "persp", "presets", "concave", "stability", "robustness"];

/// Meshes the preset sweep (speed–accuracy chart) runs on.
const PRESET_MESHES: &[&str] = &["spot.obj", "bob_tri.obj", "armadillo.obj", "cheburashka.obj", "plane.obj"];

/// One reconstruction and its scores.
pub(crate) struct Run {
    pub(crate) name: String,
    pub(crate) case: String,
    pub(crate) rig: String,
    pub(crate) preset: Preset,
    pub(crate) value: Value,
}

pub(crate) fn load_normalised(dir: &Path, file: &str) -> Result<Mesh, String> {
    let mut mesh = load_mesh(dir.join(file)).map_err(|e| e.to_string())?.without_attributes();
    mesh.normalize_unit_cube();
    if mesh.signed_volume() < 0.0 {
        mesh.flip_winding(); // horse.ply is wound inwards; oracle normals must face out
    }
    Ok(mesh)
}

/// One of [`CONCAVE`]: its table name and the mesh, normalised and, when `turned`, rotated
/// −90° about x (+y → +z) so that the opening faces the front camera.
pub(crate) fn load_concave(dir: &Path, file: &str, turned: bool) -> Result<(String, Mesh), String> {
    let mut truth = load_normalised(dir, file)?;
    let mut name = file.split('.').next().unwrap_or(file).to_string();
    if turned {
        truth.map_positions(|p| glam::Vec3::new(p.x, -p.z, p.y)).map_err(|e| e.to_string())?;
        name.push_str(" (opening to front)");
    }
    Ok((name, truth))
}

/// Reconstructs `views` and scores the result against `truth`.
pub(crate) fn score(
    name: &str,
    case: &str,
    rig_name: &str,
    truth: &Mesh,
    views: &ViewSet,
    preset: Preset,
) -> Result<Run, String> {
    score_scaled(name, case, rig_name, truth, views, preset, 1.0)
}

/// [`score`] for views of a normalised mesh scaled by `scale` (`truth` is the scaled mesh):
/// the reconstruction is scaled back by `1 / scale` before it is evaluated against the
/// normalised truth (`evaluate` normalises the truth into the unit cube), so its metrics
/// are in the units of every other table.
pub(crate) fn score_scaled(
    name: &str,
    case: &str,
    rig_name: &str,
    truth: &Mesh,
    views: &ViewSet,
    preset: Preset,
    scale: f32,
) -> Result<Run, String> {
    let mut options = ReconOptions::preset(preset);
    // Development overrides: W3D_RECON_TUNE="steps=120,lo=0.02,sphere=1".
    if let Ok(tune) = std::env::var("W3D_RECON_TUNE") {
        for kv in tune.split(',').filter(|s| !s.is_empty()) {
            let (k, v) = kv.split_once('=').ok_or(format!("W3D_RECON_TUNE: {kv}"))?;
            let x: f32 = v.parse().map_err(|e| format!("W3D_RECON_TUNE {k}: {e}"))?;
            match k {
                "steps" => options.coarse.steps = x as usize,
                "lo" => options.coarse.edge_len_lims.0 = x,
                "hi" => options.coarse.edge_len_lims.1 = x,
                "lr" => options.coarse.lr = x,
                "decay" => options.coarse.lr_decay = x,
                "lap" => options.coarse.laplacian_weight = x,
                "px" => options.coarse.min_edge_pixels = x,
                "mask" => options.coarse.mask_weight = x,
                "eps" => options.coarse.grazing_epsilon = x,
                "sphere" => options.init.force_sphere = x != 0.0,
                "hull_iou" => options.init.hull_alternative_iou = x,
                "grid" => options.init.grid = x as usize,
                "init_edge" => options.init.edge_length = x,
                "smooth" => options.init.smoothing_iterations = x as usize,
                _ => return Err(format!("W3D_RECON_TUNE: unknown key {k}")),
            }
        }
    }
    let t = Instant::now();
    let result = reconstruct(views, &options, &mut |_| {});
    let seconds = t.elapsed().as_secs_f64();
    let (mesh, report) = match result {
        Ok(r) => r,
        Err(e) => {
            eprintln!("{name:>24} {case:>12} {rig_name:>5} {preset:>8}: ERROR {e}");
            return Ok(Run {
                name: name.into(),
                case: case.into(),
                rig: rig_name.into(),
                preset,
                value: json!({ "mesh": name, "case": case, "rig": rig_name, "preset": preset, "error": e.to_string() }),
            });
        }
    };
    if let Ok(dir) = std::env::var("W3D_RECON_SAVE") {
        let stem = format!("{dir}/{name}_{case}_{rig_name}_{preset}").replace([' ', '='], "_");
        let (init, _) = wonder3d::recon::initial_mesh(views, &options.init).map_err(|e| e.to_string())?;
        wonder3d::save_mesh(format!("{stem}_init.obj"), &init).map_err(|e| e.to_string())?;
        wonder3d::save_mesh(format!("{stem}.obj"), &mesh).map_err(|e| e.to_string())?;
    }
    // The loss the original mesh itself scores against the views: the floor of the view loss
    // (None where the original is not manifold, e.g. the cow's pinch vertex).
    let truth_view_loss = wonder3d::recon::view_loss(views, &truth.merge_by_position().0, &options.coarse).ok();
    let nan = mesh.positions().iter().flatten().any(|v| !v.is_finite());
    let metrics = if scale == 1.0 {
        evaluate(&mesh, truth, &EvalOptions::default())
    } else {
        let mut unscaled = mesh.clone();
        unscaled.map_positions(|p| p / scale).map_err(|e| e.to_string())?;
        evaluate(&unscaled, truth, &EvalOptions::default())
    }
    .map_err(|e| e.to_string())?;
    let topo = mesh.topology();
    let truth_topo = truth.merge_by_position().0.topology();
    eprintln!(
        "{name:>24} {case:>12} {rig_name:>5} {preset:>8}: [{}] CD {:.4} F@.01 {:.3} F@.02 {:.3} IoU {:.3} NC {:.3} \
         {} tris {:.1} s, init {:?}, genus {:?}/{:?}",
        report.init.reason,
        metrics.chamfer,
        metrics.fscore_001,
        metrics.fscore_002,
        metrics.iou_64,
        metrics.normal_consistency,
        mesh.triangle_count(),
        seconds,
        report.init.choice,
        topo.genus(),
        truth_topo.genus()
    );
    let value = json!({
        "mesh": name,
        "case": case,
        "rig": rig_name,
        "preset": preset,
        "seconds": seconds,
        "scale": scale,
        "init_seconds": report.init.seconds,
        "coarse_seconds": report.coarse.seconds,
        "triangles": mesh.triangle_count(),
        "init": report.init,
        "losses": [report.coarse.losses.first(), report.coarse.losses.last()],
        "metrics": metrics,
        "genus": topo.genus(),
        "genus_truth": truth_topo.genus(),
        "watertight": topo.is_watertight(),
        "nan": nan,
        "self_intersections": mesh.self_intersections().len(),
        "coarse_reseeds": report.coarse_reseeds,
        "remesh_repairs": report.remesh_repairs,
        "untangle": report.untangle,
        "polish": report.polish,
        "final_loss": report.coarse.losses.last(),
        "view_loss": report.polish.loss_after,
        "truth_view_loss": truth_view_loss,
    });
    Ok(Run { name: name.into(), case: case.into(), rig: rig_name.into(), preset, value })
}

/// [`wonder3d::eval::with_normal_noise`] with the xtask's string errors.
pub(crate) fn with_normal_noise(views: ViewSet, sigma: f32, seed: u64) -> Result<ViewSet, String> {
    wonder3d::eval::with_normal_noise(views, sigma, seed).map_err(|e| e.to_string())
}

/// [`wonder3d::eval::novel_view_fidelity`] as (mean PSNR, mean SSIM), with the xtask's string errors.
pub(crate) fn novel_view_fidelity(truth: &Mesh, ours: &Mesh, size: u32) -> Result<(f64, f64), String> {
    let f = wonder3d::eval::novel_view_fidelity(truth, ours, size).map_err(|e| e.to_string())?;
    Ok((f.psnr, f.ssim))
}

/// Texture fidelity in novel views: spot and bob (textured assets) reconstructed from their
/// oracle views, baked at 1024², compared in the 16 SyncDreamer views; the same bake on the
/// ground-truth geometry for reference. Writes `target/bench/recon_texture.json`.
fn texture_cases(size: u32) -> Result<(), String> {
    use wonder3d::texture::{TextureOptions, bake};
    let rig = ViewRig::wonder3d_ortho();
    let mut rows = Vec::new();
    for file in ["spot.obj", "bob_tri.obj"] {
        let path = crate::workspace::workspace_root().join("assets").join(file);
        let mut truth = load_mesh(&path).map_err(|e| e.to_string())?;
        truth.normalize_unit_cube();
        let views = render_oracle_views(&truth, &rig, size).map_err(|e| e.to_string())?;
        let options = ReconOptions::preset(Preset::Default);
        let (mesh, report) = reconstruct(&views, &options, &mut |_| {}).map_err(|e| e.to_string())?;
        let texture = TextureOptions::default();
        let ours = bake(&mesh, &views, &texture).map_err(|e| e.to_string())?;
        let on_truth = bake(&truth.clone().without_attributes(), &views, &texture).map_err(|e| e.to_string())?;
        let (psnr_recon, ssim_recon) = novel_view_fidelity(&truth, &ours.mesh, size)?;
        let (psnr_truth, ssim_truth) = novel_view_fidelity(&truth, &on_truth.mesh, size)?;
        let name = file.split('.').next().unwrap_or(file);
        eprintln!("{name}: 16-view PSNR {psnr_recon:.2} dB (reconstructed) / {psnr_truth:.2} dB (true geometry)");
        rows.push(json!({
            "mesh": name,
            "triangles": report.triangles,
            "psnr_reconstructed": psnr_recon,
            "ssim_reconstructed": ssim_recon,
            "psnr_true_geometry": psnr_truth,
            "ssim_true_geometry": ssim_truth,
        }));
    }
    let out = crate::workspace::target_dir().join("bench").join("recon_texture.json");
    std::fs::create_dir_all(crate::workspace::target_dir().join("bench")).map_err(|e| e.to_string())?;
    std::fs::write(&out, serde_json::to_string_pretty(&rows).unwrap_or_default())
        .map_err(|e| format!("{}: {e}", out.display()))?;
    eprintln!("wrote {}", out.display());
    Ok(())
}

pub fn run(args: &[String]) -> Result<(), String> {
    let mut meshes: Option<Vec<String>> = None;
    let mut cases = ALL_CASES.to_vec();
    let mut size = 256u32;
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = || it.next().cloned().ok_or(format!("{a} needs a value"));
        match a.as_str() {
            "--meshes" => meshes = Some(value()?.split(',').map(str::to_string).collect()),
            "--cases" => {
                let v = value()?;
                cases = ALL_CASES.iter().copied().filter(|c| v.split(',').any(|x| x == *c)).collect();
            }
            "--size" => size = value()?.parse().map_err(|e| format!("--size: {e}"))?,
            "--docs-from-json" => return docs_from_json(),
            "--texture" => return texture_cases(size),
            other => return Err(format!("unknown argument {other:?} (see xtask/src/recon.rs)")),
        }
    }
    let root = crate::workspace::workspace_root();
    let data = root.join("../shared/data/meshes");
    let wanted =
        |file: &str| meshes.as_ref().is_none_or(|m| m.iter().any(|w| file.starts_with(&format!("{w}.")) || file == w));
    let mut runs: Vec<Run> = Vec::new();
    let ortho = ViewRig::wonder3d_ortho();
    let persp = ViewRig::wonder3d_persp();
    for file in CLOSED.iter().filter(|f| wanted(f)) {
        let truth = load_normalised(&data, file)?;
        let name = file.split('.').next().unwrap_or(file);
        let ortho_views = render_oracle_views(&truth, &ortho, size).map_err(|e| e.to_string())?;
        if cases.contains(&"ortho") {
            runs.push(score(name, "oracle", "ortho", &truth, &ortho_views, Preset::Default)?);
        }
        if cases.contains(&"persp") {
            let views = render_oracle_views(&truth, &persp, size).map_err(|e| e.to_string())?;
            runs.push(score(name, "oracle", "persp", &truth, &views, Preset::Default)?);
        }
        if cases.contains(&"presets") && PRESET_MESHES.contains(file) {
            for preset in [Preset::Fast, Preset::Quality] {
                runs.push(score(name, "oracle", "ortho", &truth, &ortho_views, preset)?);
            }
        }
        if cases.contains(&"stability") && (*file == "spot.obj" || *file == "bob_tri.obj") {
            for sigma in [0.05f32, 0.15] {
                let views = with_normal_noise(ortho_views.clone(), sigma, 7)?;
                let case = format!("noise σ={sigma}");
                runs.push(score(name, &case, "ortho", &truth, &views, Preset::Default)?);
            }
            // One view replaced by a wrong view: the left view shows the right view's images.
            let (rig, mut images) = ortho_views.clone().into_parts();
            let (right, left) = (2, 4);
            let wrong = images[right].clone();
            images[left].normal = wrong.normal;
            images[left].mask = wrong.mask;
            let views = ViewSet::new(rig, images).map_err(|e| e.to_string())?;
            runs.push(score(name, "wrong view", "ortho", &truth, &views, Preset::Default)?);
        }
    }
    if cases.contains(&"concave") {
        for &(file, turn) in CONCAVE {
            if !wanted(file) {
                continue;
            }
            let (name, truth) = load_concave(&data, file, turn)?;
            let views = render_oracle_views(&truth, &ortho, size).map_err(|e| e.to_string())?;
            runs.push(score(&name, "concave", "ortho", &truth, &views, Preset::Default)?);
        }
    }
    if cases.contains(&"robustness") {
        runs.extend(robustness_runs(&data, size, &wanted)?);
    }
    let out_dir = crate::workspace::target_dir().join("bench");
    std::fs::create_dir_all(&out_dir).map_err(|e| format!("{}: {e}", out_dir.display()))?;
    let out = out_dir.join("recon.json");
    let all: Vec<&Value> = runs.iter().map(|r| &r.value).collect();
    let doc = json!({ "size": size, "machine": crate::workspace::cpu_model(), "runs": all });
    std::fs::write(&out, serde_json::to_string_pretty(&doc).unwrap_or_default())
        .map_err(|e| format!("{}: {e}", out.display()))?;
    eprintln!("wrote {}", out.display());
    if meshes.is_none() && cases.len() == ALL_CASES.len() {
        let md = root.join("docs/accuracy.md");
        std::fs::write(&md, accuracy_markdown(&runs, size)).map_err(|e| format!("{}: {e}", md.display()))?;
        eprintln!("wrote {}", md.display());
    }
    let failed = robustness_failures(&runs);
    if !failed.is_empty() {
        return Err(format!("robustness cells broke an invariant:\n{}", failed.join("\n")));
    }
    Ok(())
}

/// What the tables cannot say: the objects that miss the targets and why.
const NOTES: &str = r#"
## Where and why it falls short

**hammer** (the one object far above CD 0.015). The hammer lies flat in the horizontal plane
(normalised: 0.36 × 0.08 × 1.0), and every camera of the Wonder3D rig is at elevation 0, so
all six views see it edge-on: its top-down layout (a T: head across, handle along the middle)
is in no silhouette, and a wall's normal does not say how far along the ray the wall is. The
front and back views see only the head (the handle hides behind it, a depth step integration
cannot see), so the Poisson start is a small slab whose silhouette IoU in the right view is
0.15; `reconstruct` therefore also optimises from the visual hull and keeps that result (a
settled loss about half the Poisson result's): a plate with the hull's outline, CD 0.032 instead of 0.072 for the optimised
Poisson start (two rails along the sides of the hull). Neither is the T. Left to right: ground
truth and reconstruction from 30° elevation (view 0), then view 3. A prior that prefers the
smaller of equally good shapes (a volume penalty in the coarse loss, weight 0.3) carves little
of the T (CD 0.0282) and eats what the views do show elsewhere (spot 0.0031 → 0.0188, torus
0.0092 → 0.0492), so it was dropped.

![hammer from 30° elevation: truth, reconstruction, truth, reconstruction](img/hammer_flat.png)

**bob** (genus 1, reconstructed as genus 0, CD ≈ 0.011) and **torus**. Bob is a duck-shaped
swim ring whose hole is vertical: no view at elevation 0 looks through it, so the hole is not
in the data and the reconstruction closes it (truth and reconstruction from 30° elevation,
two azimuths). The torus also lies flat; its genus in the tables comes from the optimiser,
not from evidence in the views. Rocker-arm's through-hole is visible from the side views and
is kept (genus 1).

![bob from 30° elevation: truth, reconstruction, truth, reconstruction](img/bob_hole_unseen.png)

**teacup / teapot** are open meshes (their volume IoU is not meaningful: the winding-number
inside test of an open cup is ill-defined), so only CD and F-score count there. The upright
teacup's interior is seen by no view at elevation 0 and is filled. Turned to open towards the
front camera, the saucer dominates the silhouette and the concave check does not fire; the
check is proven on a closed bowl in `crates/w3d-recon/tests/reconstruction/init.rs`. For both teacups the
Poisson start misses the side silhouettes (the handle and the saucer's rim), and the
visual-hull start reaches a loss about a third lower and is kept. In the perspective rig the
hammer's two results explain the views about equally well (settled losses within ±20 % of
each other from seed to seed), so the Poisson result is kept (CD about 0.03; the hull's
would be 0.022): the same ambiguity, decided by the rule rather than by the last bits of the
loss.

**Self-intersections.** Continuous remeshing has no self-intersection guard (the reference
has none either): the coarse stage leaves crossing triangle pairs — a few on convex objects,
hundreds where two sheets are pushed together (plane wings, the rocker arm's thin rims) or
the surface crumples into tiny folded triangles (on the teapot, edges of about 0.002 where
the lower limit is 0.02). `w3d_recon::untangle` then moves only the vertices of the crossing
triangles, in rounds (400 at most): a *separation* round gives each crossing pair the smallest move that puts one triangle wholly on
one side of the other's plane, 5 % of an edge past it (so thin parts keep their thickness and
outline), and when that stops helping, a *smoothing* round moves them half way to their
neighbours' average; every 8 rounds without a new fewest count the smoothed neighbourhood
grows by a ring (4 at most, back to none at the next new fewest), and the positions with the
fewest crossings seen are returned; after the first full check a round re-checks only
the triangles it moved. In the rare case crossings are left (1 of 154 coarse meshes measured:
14 oracle meshes and the teapot and teacups, both rigs, presets, remesher seeds 0–5), the
coarse stage runs again from the same start with the next remesher seed, and if that fails
too, twice more with the following seeds and the remesher's repairs on (fold relaxation,
valence-3 removal, floor collapses: they leave far fewer of the crumpled patches of sub-floor
triangles that contradictory views cause, see the robustness table, at a cost in detail);
"reseeded" in the tables, with "repairs" when the run kept had them. The tables give the count found by `Mesh::self_intersections`
before and after: every run above ends without crossings. Untangling alone costs accuracy where it has
much to do: it thinned the plane's wings and the rocker arm's rims (CD 0.0030 → 0.0045 and
0.0062 → 0.0094 against the crossing coarse meshes) and multiplied their view loss (0.028 →
0.156, 0.023 → 0.170). `w3d_recon::polish` therefore fits the vertices it moved (and two rings
around them) to the views again for 40 steps, undoing any move that would make triangles
cross: plane CD 0.0039, rocker arm 0.0075, view losses 0.091 and 0.062, under a second each.
The last column gives the final view loss (the coarse stage's loss, all six views) and, in
brackets, the loss of the original mesh against its own views. No result reaches that floor:
edges of at least 2 pixels and smooth vertex normals leave about 0.01–0.03 on smooth objects,
about half of it along the silhouettes. The hammer's 0.0154 is as low as spot's 0.0163 (per
view, silhouette terms 0.0002–0.0027 against spot's 0.0007–0.0019): its plate matches the
views as well as spot's result does, at ten times the Chamfer distance, which is the
ambiguity described above and not an optimisation left unfinished. Tried and measured worse, on the
orthographic rig: smoothing the crossings every 5 steps inside the coarse stage (koala CD 0.0039 → 0.0112, plane 0.0044 → 0.0149),
undoing each step's moves that make triangles cross (koala 0.0143), the same smoothing in the
last 20 % of the steps only (plane 0.0090: the wings' loss rose from 0.028 to 0.16), a final
remesh with the remesher's repairs on (plane 0.0194: its floor collapses fold the thin wings),
and six rings of smoothing from the start (rocker arm 0.0128, still crossing).

**Run-to-run sensitivity.** The coarse stage is chaotic: the remesher's splits, collapses and
flips are discrete choices, so a change in the last bits of the input changes which edges
are touched at some step, and from there the whole trajectory. When the oracle normals moved
to the shared `w3d_core::normals` (vertex-normal sums in f64 instead of f32: the rendered
normals moved by about 1e-7), every cell of the perspective table changed (spot CD 0.0030 →
0.0031, torus 0.0140 → 0.0160, hammer 0.0224 → 0.0293) with nothing else changed; reverting
that one function of `w3d-raster` restored every number bit for bit. The spread of a cell
under such perturbations (uniform noise of ±1e-6 on the oracle normals, the clean views and
five noise seeds; every run without crossings): plane, perspective, CD 0.0026–0.0052 (median
0.0028); torus, perspective, 0.0141–0.0158; spot, perspective, 0.0029–0.0031; plane, quality
preset, 0.0030–0.0050 — read single cells of the tables with that spread in mind. Two choices made on a noisy number were the fragile part, and now have margins: the
visual-hull alternative start is kept only when its settled loss (mean of the last 10 % of
steps) is more than 25 % below the Poisson result's (`InitOptions::hull_alternative_margin`;
before, the lower last-step loss won, and the plane in the perspective rig went from
Poisson, CD 0.0031, to the hull, CD 0.0063, on those last bits), and untangling judges
progress against the fewest crossings seen (above; before, spot in the perspective rig kept 3
of 59 crossing pairs and the plane at the quality preset 9 of 2024). The new untangling rule
has a cost where the old one succeeded: from the same coarse mesh (492 crossing pairs) it
smooths the rocker arm's thin rims over more rings, CD 0.0068 → 0.0081 in the orthographic
table (view loss 0.067 → 0.102); every other cell of the ortho table moved by 0.0001 at most.
"#;

/// Rewrites `docs/accuracy.md` from the last full run's `target/bench/recon.json` (after
/// editing the prose, without reconstructing again).
fn docs_from_json() -> Result<(), String> {
    let path = crate::workspace::target_dir().join("bench").join("recon.json");
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let doc: Value = serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    let size = doc["size"].as_u64().ok_or(format!("{}: no size", path.display()))? as u32;
    let mut runs = Vec::new();
    for v in doc["runs"].as_array().ok_or(format!("{}: no runs", path.display()))? {
        let text = |k: &str| v[k].as_str().unwrap_or_default().to_string();
        let preset: Preset = text("preset").parse().map_err(|e| format!("{}: {e}", path.display()))?;
        runs.push(Run { name: text("mesh"), case: text("case"), rig: text("rig"), preset, value: v.clone() });
    }
    let md = crate::workspace::workspace_root().join("docs/accuracy.md");
    std::fs::write(&md, accuracy_markdown(&runs, size)).map_err(|e| format!("{}: {e}", md.display()))?;
    eprintln!("wrote {}", md.display());
    Ok(())
}

pub(crate) fn f(v: &Value, path: &[&str]) -> f64 {
    let mut v = v;
    for p in path {
        v = &v[*p];
    }
    v.as_f64().unwrap_or(f64::NAN)
}

fn table(runs: &[&Run]) -> String {
    let mut s = String::from(
        "| mesh | CD | F@0.01 | F@0.02 | IoU 64³ | normal cons. | triangles | seconds | init | genus (truth) | crossing pairs (coarse → untangled) | view loss (of the truth) |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let mut sums = [0.0f64; 7];
    let mut count = 0.0;
    let (mut sums_wo, mut count_wo) = ([0.0f64; 7], 0.0);
    for r in runs {
        let v = &r.value;
        if v.get("error").is_some() {
            s.push_str(&format!("| {} | error: {} |||||||||||\n", r.name, v["error"]));
            continue;
        }
        let row = [
            f(v, &["metrics", "chamfer"]),
            f(v, &["metrics", "fscore_0.01"]),
            f(v, &["metrics", "fscore_0.02"]),
            f(v, &["metrics", "iou_64"]),
            f(v, &["metrics", "normal_consistency"]),
            f(v, &["triangles"]),
            f(v, &["seconds"]),
        ];
        for (a, b) in sums.iter_mut().zip(row) {
            *a += b;
        }
        count += 1.0;
        if r.name != "hammer" {
            for (a, b) in sums_wo.iter_mut().zip(row) {
                *a += b;
            }
            count_wo += 1.0;
        }
        s.push_str(&format!(
            "| {} | {:.4} | {:.3} | {:.3} | {:.3} | {:.3} | {} | {:.1} | {} | {} ({}) | {} → {}{} | {} ({}) |\n",
            r.name,
            row[0],
            row[1],
            row[2],
            row[3],
            row[4],
            row[5],
            row[6],
            v["init"]["choice"].as_str().unwrap_or("?"),
            v["genus"],
            v["genus_truth"],
            v["untangle"]["before"],
            v["self_intersections"],
            reseeded(v),
            v["view_loss"].as_f64().map_or("–".into(), |x| format!("{x:.4}")),
            v["truth_view_loss"].as_f64().map_or("–".into(), |x| format!("{x:.4}")),
        ));
    }
    if count > 0.0 {
        let m: Vec<f64> = sums.iter().map(|x| x / count).collect();
        s.push_str(&format!(
            "| **mean** | **{:.4}** | **{:.3}** | **{:.3}** | **{:.3}** | {:.3} | {:.0} | {:.1} | | | | |\n",
            m[0], m[1], m[2], m[3], m[4], m[5], m[6]
        ));
        if count_wo < count && count_wo > 0.0 {
            let m: Vec<f64> = sums_wo.iter().map(|x| x / count_wo).collect();
            s.push_str(&format!(
                "| mean without hammer (see below) | {:.4} | {:.3} | {:.3} | {:.3} | {:.3} | {:.0} | {:.1} | | | | |\n",
                m[0], m[1], m[2], m[3], m[4], m[5], m[6]
            ));
        }
    }
    s
}

/// " (reseeded N)" when the coarse stage ran again because untangling left crossings,
/// " (…, repairs)" when the run kept is the one with the remesher's repairs on.
pub(crate) fn reseeded(v: &Value) -> String {
    match (v["coarse_reseeds"].as_u64(), v["remesh_repairs"].as_bool()) {
        (Some(n), Some(true)) if n > 0 => format!(" (reseeded {n}, repairs)"),
        (Some(n), _) if n > 0 => format!(" (reseeded {n})"),
        _ => String::new(),
    }
}

fn accuracy_markdown(runs: &[Run], size: u32) -> String {
    let pick = |case: &str, rig: &str, preset: Preset| -> Vec<&Run> {
        runs.iter().filter(|r| r.case == case && r.rig == rig && r.preset == preset).collect()
    };
    let mut s = format!(
        "# Reconstruction accuracy\n\n\
         Generated by `cargo xtask bench recon` (do not edit by hand; prose lives in the \
         generator, `xtask/src/recon.rs`). Oracle views: each mesh of `../shared/data/meshes`, \
         normalised to the unit cube, rendered by `w3d-raster` into the rig at {size}², then \
         `w3d_recon::reconstruct` with the preset named, evaluated by `w3d-eval` against the \
         normalised original (100k samples, no alignment). Machine: {}. Seconds are wall-clock \
         for init + coarse on 2 cores.\n\n",
        crate::workspace::cpu_model()
    );
    s.push_str("## Wonder3D orthographic rig, default preset\n\n");
    s.push_str(&table(&pick("oracle", "ortho", Preset::Default)));
    s.push_str("\n## Wonder3D perspective rig (35 mm), default preset\n\n");
    s.push_str(&table(&pick("oracle", "persp", Preset::Default)));
    s.push_str(
        "\n## Presets (orthographic rig)\n\nThe speed–accuracy chart `docs/speed_accuracy.svg` plots these.\n\n",
    );
    for preset in Preset::ALL {
        let rows: Vec<&Run> = runs
            .iter()
            .filter(|r| r.case == "oracle" && r.rig == "ortho" && r.preset == preset)
            .filter(|r| PRESET_MESHES.iter().any(|m| m.starts_with(&format!("{}.", r.name))))
            .collect();
        s.push_str(&format!("### {preset}\n\n{}\n", table(&rows)));
    }
    s.push_str("## Concave objects\n\n");
    s.push_str(
        "The concave check compares the centre and silhouette mean depths of the integrated front \
         and back views (see `w3d_recon::initial_mesh`); `front`/`back` are centre − mean depth.\n\n\
         | object | start | front | back | CD | F@0.02 | IoU 64³ | NaN | watertight | crossing pairs after coarse | after untangle | view loss (of the truth) |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in runs.iter().filter(|r| r.case == "concave") {
        let v = &r.value;
        s.push_str(&format!(
            "| {} | {} | {:+.4} | {:+.4} | {:.4} | {:.3} | {:.3} | {} | {} | {} | {}{} | {} ({}) |\n",
            r.name,
            v["init"]["choice"].as_str().unwrap_or("?"),
            f(v, &["init", "front_concavity"]),
            f(v, &["init", "back_concavity"]),
            f(v, &["metrics", "chamfer"]),
            f(v, &["metrics", "fscore_0.02"]),
            f(v, &["metrics", "iou_64"]),
            v["nan"],
            v["watertight"],
            v["untangle"]["before"],
            v["self_intersections"],
            reseeded(v),
            v["view_loss"].as_f64().map_or("–".into(), |x| format!("{x:.4}")),
            v["truth_view_loss"].as_f64().map_or("–".into(), |x| format!("{x:.4}")),
        ));
    }
    let texture_json = crate::workspace::target_dir().join("bench").join("recon_texture.json");
    if let Ok(text) = std::fs::read_to_string(&texture_json)
        && let Ok(Value::Array(rows)) = serde_json::from_str::<Value>(&text)
    {
        s.push_str(
                "\n## Texture in novel views (`cargo xtask bench recon -- --texture`)\n\n\
                 Spot and bob (textured assets) reconstructed from their 6 oracle views (default preset), \
                 baked at 1024² by `w3d-texture`, rendered in the 16 SyncDreamer views with their masks, \
                 composited over white and compared with the textured original; the same bake on the \
                 true geometry for reference.\n\n\
                 | mesh | PSNR, reconstructed | SSIM, reconstructed | PSNR, true geometry | SSIM, true geometry |\n|---|---|---|---|---|\n",
            );
        for r in &rows {
            s.push_str(&format!(
                "| {} | {:.2} dB | {:.4} | {:.2} dB | {:.4} |\n",
                r["mesh"].as_str().unwrap_or("?"),
                f(r, &["psnr_reconstructed"]),
                f(r, &["ssim_reconstructed"]),
                f(r, &["psnr_true_geometry"]),
                f(r, &["ssim_true_geometry"]),
            ));
        }
    }
    s.push_str(NOTES);
    s.push_str("\n## Stability (orthographic rig, default preset)\n\n");
    s.push_str("Gaussian noise of σ added to each normal component inside the masks (then renormalised); \"wrong view\": the left view's normal map and mask replaced by the right view's.\n\n");
    s.push_str("| mesh | case | CD | F@0.02 | IoU 64³ | NaN | seconds |\n|---|---|---|---|---|---|---|\n");
    for r in runs.iter().filter(|r| r.case.starts_with("noise") || r.case == "wrong view") {
        let v = &r.value;
        s.push_str(&format!(
            "| {} | {} | {:.4} | {:.3} | {:.3} | {} | {:.1} |\n",
            r.name,
            r.case,
            f(v, &["metrics", "chamfer"]),
            f(v, &["metrics", "fscore_0.02"]),
            f(v, &["metrics", "iou_64"]),
            v["nan"],
            f(v, &["seconds"]),
        ));
    }
    s.push_str(&robustness_markdown(runs));
    s
}

/// Runs every robustness case ([`robust::CASES`]) on the meshes of [`robust::MESHES`] that
/// `wanted` accepts.
fn robustness_runs(data: &Path, size: u32, wanted: &dyn Fn(&str) -> bool) -> Result<Vec<Run>, String> {
    let rig = ViewRig::wonder3d_ortho();
    let mut runs = Vec::new();
    for (index, file) in robust::MESHES.iter().enumerate() {
        if !wanted(file) {
            continue;
        }
        let name = file.split('.').next().unwrap_or(file);
        let truth = load_normalised(data, file)?;
        let clean = render_oracle_views(&truth, &rig, size).map_err(|e| e.to_string())?;
        let seed = robust::NOISE_SEED + index as u64;
        for &case in robust::CASES {
            // What was drawn at random, for recon.json (the per-view scales and shifts).
            let mut detail = Value::Null;
            // (truth the views show, its scale, the views)
            let perturbed: Result<(Mesh, f32, ViewSet), String> = match case {
                "noise σ=0" => Ok((truth.clone(), 1.0, clean.clone())),
                "noise σ=0.05" | "noise σ=0.15" | "noise σ=0.3" => {
                    let sigma: f32 = case.trim_start_matches("noise σ=").parse().map_err(|e| format!("{e}"))?;
                    with_normal_noise(clean.clone(), sigma, seed).map(|v| (truth.clone(), 1.0, v))
                }
                "blur σ=2 px" => robust::with_blurred_normals(clean.clone(), 2.0).map(|v| (truth.clone(), 1.0, v)),
                "normal rotation 5°" | "normal rotation 10°" => {
                    let degrees = if case.contains("10°") { 10.0 } else { 5.0 };
                    robust::with_rotated_normals(clean.clone(), degrees, seed).map(|v| (truth.clone(), 1.0, v))
                }
                "scale jitter ±3 %" => {
                    robust::with_scale_jitter(clean.clone(), robust::SCALE_JITTER, seed).map(|(v, factors)| {
                        detail = json!({ "view_scales": factors });
                        (truth.clone(), 1.0, v)
                    })
                }
                "shift ±2 px" => robust::with_shifts(clean.clone(), robust::SHIFT_PX, seed).map(|(v, shifts)| {
                    detail = json!({ "view_shifts_px": shifts });
                    (truth.clone(), 1.0, v)
                }),
                "silhouette dilated 3 px" | "silhouette eroded 3 px" => {
                    let radius = if case.contains("dilated") { robust::SILHOUETTE_PX } else { -robust::SILHOUETTE_PX };
                    robust::with_silhouette_changed(clean.clone(), robust::ONE_VIEW, radius)
                        .map(|v| (truth.clone(), 1.0, v))
                }
                "one view from another shape" => {
                    let other = robust::other_shape(&truth)?;
                    let donor = render_oracle_views(&other, &rig, size).map_err(|e| e.to_string())?;
                    robust::with_geometry_from(clean.clone(), &donor, robust::ONE_VIEW).map(|v| (truth.clone(), 1.0, v))
                }
                "mirrored back (two faces)" => {
                    robust::with_mirrored_back(clean.clone()).map(|v| (truth.clone(), 1.0, v))
                }
                "wrong view" => {
                    let donor = load_normalised(data, robust::MESHES[(index + 1) % robust::MESHES.len()])?;
                    let donor_views = render_oracle_views(&donor, &rig, size).map_err(|e| e.to_string())?;
                    robust::with_view_from(clean.clone(), &donor_views, "front_right").map(|v| (truth.clone(), 1.0, v))
                }
                "missing view (left)" | "missing view (front)" => {
                    let missing = if case.contains("left") { "left" } else { "front" };
                    let keep: Vec<&str> = rig.views.iter().map(|v| v.name.as_str()).filter(|&n| n != missing).collect();
                    clean.subset(keep).map(|v| (truth.clone(), 1.0, v)).map_err(|e| e.to_string())
                }
                "exposure per view" => {
                    robust::with_exposures(clean.clone(), &robust::EXPOSURES).map(|v| (truth.clone(), 1.0, v))
                }
                "object at 40 % of the frame" | "object at 95 % of the frame" => {
                    let fraction = if case.contains("40") { 0.40 } else { 0.95 };
                    let (scaled, scale) = robust::scaled_to_frame(&truth, &rig, size, fraction)?;
                    let views = render_oracle_views(&scaled, &rig, size).map_err(|e| e.to_string())?;
                    Ok((scaled, scale, views))
                }
                "views at 128²" | "views at 512²" => {
                    let s = if case.contains("128") { 128 } else { 512 };
                    render_oracle_views(&truth, &rig, s).map(|v| (truth.clone(), 1.0, v)).map_err(|e| e.to_string())
                }
                other => Err(format!("unknown robustness case {other}")),
            };
            let label = format!("{}{case}", robust::PREFIX);
            let mut run = match perturbed {
                Ok((truth, scale, views)) => checked_score(name, &label, &truth, scale, &views),
                Err(e) => failed_run(name, &label, "error", e),
            };
            if !detail.is_null() {
                run.value["perturbation"] = detail;
            }
            runs.push(run);
        }
    }
    Ok(runs)
}

/// [`score_scaled`] with a panic or an error recorded in the run instead of ending the bench.
fn checked_score(name: &str, case: &str, truth: &Mesh, scale: f32, views: &ViewSet) -> Run {
    match catch_unwind(AssertUnwindSafe(|| score_scaled(name, case, "ortho", truth, views, Preset::Default, scale))) {
        Ok(Ok(run)) => run,
        Ok(Err(e)) => failed_run(name, case, "error", e),
        Err(panic) => {
            let message = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "a panic without a message".into());
            eprintln!("{name:>24} {case}: PANIC {message}");
            failed_run(name, case, "panic", message)
        }
    }
}

fn failed_run(name: &str, case: &str, kind: &str, message: String) -> Run {
    Run {
        name: name.into(),
        case: case.into(),
        rig: "ortho".into(),
        preset: Preset::Default,
        value: json!({ "mesh": name, "case": case, "rig": "ortho", "preset": Preset::Default, kind: message }),
    }
}

/// The robustness cells that broke an invariant, as `mesh, case: what` lines.
fn robustness_failures(runs: &[Run]) -> Vec<String> {
    runs.iter()
        .filter(|r| robust::is_robustness(&r.case))
        .flat_map(|r| {
            robust::broken(&r.value)
                .into_iter()
                .map(move |b| format!("{}, {}: {b}", r.name, r.case.trim_start_matches(robust::PREFIX)))
        })
        .collect()
}

/// The robustness section of `docs/accuracy.md` (empty without robustness runs).
fn robustness_markdown(runs: &[Run]) -> String {
    let cells: Vec<&Run> = runs.iter().filter(|r| robust::is_robustness(&r.case)).collect();
    if cells.is_empty() {
        return String::new();
    }
    let mut meshes: Vec<&str> = Vec::new();
    for r in &cells {
        if !meshes.contains(&r.name.as_str()) {
            meshes.push(&r.name);
        }
    }
    let mut s = String::from("\n## Robustness (orthographic rig, default preset)\n\n");
    s.push_str(robust::PROSE);
    s.push_str("| perturbation |");
    for m in &meshes {
        s.push_str(&format!(" {m} |"));
    }
    s.push_str(" mean CD | mean IoU | mean seconds | panic / error / NaN / crossings |\n|---|");
    s.push_str(&"---|".repeat(meshes.len() + 4));
    s.push('\n');
    for case in robust::CASES {
        let label = format!("{}{case}", robust::PREFIX);
        let row: Vec<&&Run> = cells.iter().filter(|r| r.case == label).collect();
        if row.is_empty() {
            continue;
        }
        s.push_str(&format!("| {case} |"));
        let (mut cd, mut iou, mut seconds, mut n) = (0.0, 0.0, 0.0, 0.0);
        let (mut problems, mut reruns) = (Vec::new(), Vec::new());
        for m in &meshes {
            match row.iter().find(|r| r.name == *m) {
                Some(r)
                    if robust::broken(&r.value).iter().all(|b| !b.starts_with("panic") && !b.starts_with("error")) =>
                {
                    let v = &r.value;
                    let (c, i, t) = (f(v, &["metrics", "chamfer"]), f(v, &["metrics", "iou_64"]), f(v, &["seconds"]));
                    s.push_str(&format!(" {c:.4} / {i:.3} / {t:.1} |"));
                    cd += c;
                    iou += i;
                    seconds += t;
                    n += 1.0;
                    problems.extend(robust::broken(v).into_iter().map(|b| format!("{m}: {b}")));
                    if let Some(n) = v["coarse_reseeds"].as_u64().filter(|&n| n > 0) {
                        let repairs = if v["remesh_repairs"].as_bool() == Some(true) { ", repairs" } else { "" };
                        reruns.push(format!("{m} {n}{repairs}"));
                    }
                }
                Some(r) => {
                    s.push_str(" – |");
                    problems.extend(robust::broken(&r.value).into_iter().map(|b| format!("{m}: {b}")));
                }
                None => s.push_str(" |"),
            }
        }
        let mean = |x: f64| if n > 0.0 { x / n } else { f64::NAN };
        let mut checks = if problems.is_empty() { "none".to_string() } else { problems.join("; ") };
        if !reruns.is_empty() {
            checks.push_str(&format!(" (coarse reruns: {})", reruns.join(", ")));
        }
        s.push_str(&format!(" {:.4} | {:.3} | {:.1} | {checks} |\n", mean(cd), mean(iou), mean(seconds)));
    }
    let failed = robustness_failures(runs);
    s.push_str(&if failed.is_empty() {
        format!("\nAll {} cells: no panic, no error, no NaN, no self-intersection.\n", cells.len())
    } else {
        format!("\n**{} of {} cells broke an invariant** (listed in the last column).\n", failed.len(), cells.len())
    });
    s
}
