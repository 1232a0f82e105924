//! `wonder3d refine MESH VIEWS --enhancer DIR|identity|oracle:MESH --out X.glb`: the refinement
//! loop (enhance four views at `--size` → refine the mesh → refine the texture), after
//! `wonder3d reconstruct`; the diffusion enhancer takes the training-free accelerations of
//! `generate` (`--guidance-interval`, `--cache-interval`, …).

use std::path::PathBuf;

use wonder3d::core::io::write_atomic;
use wonder3d::outputs::{check_distinct, check_outputs, mesh_output_files};
use wonder3d::refine::{
    Enhancer, IdentityEnhancer, OracleEnhancer, RefineOptions, RefineProgress, RefineStep, Refined, refine,
};
use wonder3d::{Error, Mesh, Result, TextureOptions, ViewSet, save_mesh};

use crate::args::AccelerationArgs;
use crate::progress;

/// `--enhancer`: where the enhanced views come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum EnhancerArg {
    /// The renders themselves: the loop only re-fits the mesh at the finer resolution.
    Identity,
    /// Renders of a known mesh (the best any enhancer could do).
    Oracle(PathBuf),
    /// The diffusion enhancer, loaded from a model directory or a Hugging Face Hub id
    /// (`docs/weights.md`, "The enhancer").
    Diffusion(PathBuf),
}

/// Parses `--enhancer`: `identity`, `oracle:MESH` or the directory (or Hub id) of a diffusion
/// enhancer.
pub fn enhancer(s: &str) -> std::result::Result<EnhancerArg, String> {
    match s {
        "identity" => Ok(EnhancerArg::Identity),
        "" => Err("identity, oracle:MESH, an enhancer model directory or a Hub id (found an empty value)".into()),
        _ => match s.strip_prefix("oracle:") {
            Some("") => Err("oracle:MESH needs a mesh file after the colon".into()),
            Some(mesh) => Ok(EnhancerArg::Oracle(PathBuf::from(mesh))),
            None => Ok(EnhancerArg::Diffusion(PathBuf::from(s))),
        },
    }
}

/// Arguments of `wonder3d refine`.
#[derive(clap::Args)]
#[command(mut_args(crate::args::for_the_enhancer))]
pub struct RefineArgs {
    /// The closed mesh reconstructed from VIEWS (e.g. by `wonder3d reconstruct`), in the views'
    /// world frame; its uvs, colours and texture are ignored.
    mesh: PathBuf,
    /// The view-set folder the mesh was reconstructed from, with colour views (`wonder3d
    /// render` or `wonder3d generate` writes one); its rig must have the front, right, back and
    /// left views.
    views: PathBuf,
    /// Enhancer: a model directory or a Hugging Face Hub id owner/name[@revision][:sub/folder]
    /// of one, downloaded once into the Hugging Face cache (the diffusion enhancer: Stable
    /// Diffusion 1.5 + Wonder3D++'s ControlNet + IP-Adapter, layout in docs/weights.md, "The
    /// enhancer"), `identity` (the renders of the current mesh, unchanged) or `oracle:MESH`
    /// (renders of MESH, oriented outward and normalised into the unit cube as `wonder3d render`
    /// does; `--no-normalize` keeps its coordinates).
    #[arg(long, value_parser = enhancer, value_name = "DIR|HUB_ID|identity|oracle:MESH")]
    enhancer: EnhancerArg,
    /// Output file: `.glb` (embedded texture), `.obj` (+ `.mtl` + `.png`) or `.ply`.
    #[arg(long)]
    out: PathBuf,
    /// Refinement iterations (the reference runs 2; 0 textures MESH as `wonder3d run` would).
    #[arg(long, default_value_t = RefineOptions::default().iterations, allow_hyphen_values = true, value_parser = crate::args::refine_iterations)]
    iterations: usize,
    /// Side of the renders and enhanced views in pixels (the reference: 512).
    #[arg(long, default_value_t = RefineOptions::default().size, allow_hyphen_values = true, value_parser = crate::args::view_size)]
    size: u32,
    /// Texture width and height in texels.
    #[arg(long, default_value_t = TextureOptions::default().size, allow_hyphen_values = true, value_parser = crate::args::texture_size)]
    texture_size: u32,
    /// Simplify each refined mesh to this tolerance in world units (quadric edge collapse:
    /// removes the triangles the shape does not need; default 0.0005), or `off` to keep every
    /// triangle of the fit.
    #[arg(long, allow_hyphen_values = true, value_parser = crate::args::simplify)]
    simplify: Option<crate::args::Simplify>,
    /// Use the oracle mesh in its own coordinates (for views rendered with `wonder3d render
    /// --no-normalize`).
    #[arg(long)]
    no_normalize: bool,
    /// Also write the refinement report (per iteration: fit losses, untangle, texture
    /// projection, seconds) as JSON.
    #[arg(long)]
    report: Option<PathBuf>,
    #[command(flatten)]
    acceleration: AccelerationArgs,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

/// Runs `wonder3d refine`.
pub fn run(args: &RefineArgs) -> Result<()> {
    check_outputs(("--out", &args.out), args.report.as_deref().map(|r| ("--report", r)), None)?;
    let written = mesh_output_files(&args.out);
    let mut outputs: Vec<(&str, &std::path::Path)> = written.iter().map(|f| ("--out", f.as_path())).collect();
    outputs.extend(args.report.as_deref().map(|report| ("--report", report)));
    let view_files = wonder3d::ViewSet::input_files(&args.views);
    let mut inputs = vec![("MESH", args.mesh.as_path())];
    inputs.extend(view_files.iter().map(|f| ("VIEWS", f.as_path())));
    if let EnhancerArg::Oracle(oracle) = &args.enhancer {
        inputs.push(("--enhancer oracle:", oracle.as_path()));
    }
    check_distinct(&outputs, &inputs)?;
    // Checked whatever the enhancer (identity and oracle ignore them), before any work.
    let described = args.acceleration.check()?;
    let acceleration = if matches!(args.enhancer, EnhancerArg::Diffusion(_)) { described } else { "none".into() };
    let texture = TextureOptions::default().with_size(args.texture_size);
    texture.validate()?;
    let mut options =
        RefineOptions::default().with_iterations(args.iterations).with_size(args.size).with_texture(texture);
    if let Some(crate::args::Simplify(tolerance)) = args.simplify {
        options = options.clone().with_mesh(options.mesh.with_simplify_tolerance(tolerance));
    }
    let mut geometry = wonder3d::load_mesh_with_surface(&args.mesh, "MESH")?.without_attributes();
    // Refinement fits a closed surface to the enhanced views; an open or torn mesh would be
    // "refined" into something the views never showed.
    if !geometry.merge_by_position().0.topology().is_watertight() {
        return Err(Error::invalid(
            format!("MESH {}", args.mesh.display()),
            "a closed mesh, every edge shared by two triangles (wonder3d reconstruct writes one)",
        ));
    }
    crate::args::orient_outward(&mut geometry, &args.mesh);
    let enhancer: Box<dyn Enhancer> = match &args.enhancer {
        EnhancerArg::Identity => Box::new(IdentityEnhancer),
        EnhancerArg::Oracle(path) => {
            // Renders of a mesh without area are empty: every view would say "nothing here".
            let mut truth = wonder3d::load_mesh_with_surface(path, "--enhancer oracle:")?;
            crate::args::orient_outward(&mut truth, path);
            if !args.no_normalize {
                truth.normalize_unit_cube();
            }
            Box::new(OracleEnhancer::new(truth))
        }
        EnhancerArg::Diffusion(dir) => diffusion_enhancer(dir, None, Some(&args.acceleration), args.quiet)?,
    };
    let views = ViewSet::load(&args.views)?;
    // What the views see of the mesh is about both inputs: name them.
    let both = format!("MESH {} in VIEWS {}", args.mesh.display(), args.views.display());
    let refined = crate::args::name_acceleration_flags(wonder3d::outputs::for_flag(
        &both,
        refine_with_bar(&geometry, &views, enhancer.as_ref(), &options, args.quiet),
    ))?;
    save_mesh(&args.out, &refined.mesh)?;
    if let Some(path) = &args.report {
        let mut report = serde_json::to_value(&refined.report).map_err(|e| Error::invalid("report", e.to_string()))?;
        if let Some(object) = report.as_object_mut() {
            object.insert("acceleration".into(), acceleration.clone().into());
        }
        let json = serde_json::to_vec_pretty(&report).map_err(|e| Error::invalid("report", e.to_string()))?;
        write_atomic(path, |w| std::io::Write::write_all(w, &json).map_err(|e| Error::io(path, e)))?;
    }
    println!("{}{} -> {}", summary(&refined.report), crate::args::acceleration_note(&acceleration), args.out.display());
    Ok(())
}

/// The one-line summary of a refinement printed by `refine`, `reconstruct` and `run`.
pub fn summary(r: &wonder3d::refine::RefineReport) -> String {
    let kept: Vec<String> =
        r.iterations.iter().enumerate().filter(|(_, i)| i.mesh.kept_input).map(|(k, _)| (k + 1).to_string()).collect();
    let kept = match kept.len() {
        0 => String::new(),
        1 => format!(" (iteration {} kept its input mesh: the fit agreed no better with the enhanced views)", kept[0]),
        _ => format!(
            " (iterations {} kept their input mesh: the fit agreed no better with the enhanced views)",
            kept.join(", ")
        ),
    };
    format!(
        "refined with the {} enhancer: {} iteration(s), {} triangles in {:.1} s{kept}",
        r.enhancer,
        r.iterations.len(),
        r.triangles,
        r.seconds
    )
}

/// [`refine`] with a progress bar (none with `quiet`).
pub fn refine_with_bar(
    geometry: &Mesh,
    views: &ViewSet,
    enhancer: &dyn Enhancer,
    options: &RefineOptions,
    quiet: bool,
) -> Result<Refined> {
    let bar = progress::bar(quiet)?;
    let refined = refine(geometry, views, enhancer, options, &mut |p: RefineProgress| {
        bar.set_prefix(format!("refine {}/{}", p.iteration + 1, p.iterations));
        match p.step {
            RefineStep::Enhancing => {
                bar.set_message("enhancing");
                bar.set_position(0);
            }
            RefineStep::Fitting { done, total, loss } => {
                bar.set_length(total as u64);
                bar.set_position(done as u64);
                bar.set_message(format!("loss {loss:.5}"));
            }
            RefineStep::Texturing => bar.set_message("texturing"),
            _ => {}
        }
    })?;
    bar.finish_and_clear();
    Ok(refined)
}

/// `--enhancer DIR` and `--refine N` of `wonder3d run` and `wonder3d reconstruct`: Wonder3D++'s
/// refinement after the coarse mesh, with the diffusion enhancer.
#[derive(clap::Args)]
pub struct RefineAfterArgs {
    /// Refine the mesh with the diffusion enhancer in this directory, or of this Hugging Face Hub
    /// id owner/name[@revision][:sub/folder] (downloaded once into the Hugging Face cache,
    /// before any other work) (Stable Diffusion 1.5 + Wonder3D++'s ControlNet + IP-Adapter;
    /// docs/weights.md, "The enhancer"; docs/refinement.md).
    #[arg(long, value_name = "DIR|HUB_ID")]
    enhancer: Option<PathBuf>,
    /// Refinement iterations: 2 by default with --enhancer (the authors' count), 0 without;
    /// 0 writes the coarse mesh, as without --enhancer.
    #[arg(long, allow_hyphen_values = true, value_parser = crate::args::refine_iterations)]
    refine: Option<usize>,
    /// Side of the refinement's renders and enhanced views in pixels (the reference: 512).
    #[arg(long, default_value_t = RefineOptions::default().size, allow_hyphen_values = true, value_parser = crate::args::view_size)]
    refine_size: u32,
}

impl RefineAfterArgs {
    /// The iterations to run, checked before any work: more than 0 needs `--enhancer`, whose
    /// directory must hold every file of its layout (a Hub id is downloaded here, its bar
    /// hidden when `quiet`, so that a missing repository is named before the work starts).
    pub fn check(&self, quiet: bool) -> Result<usize> {
        let iterations =
            self.refine.unwrap_or(if self.enhancer.is_some() { RefineOptions::default().iterations } else { 0 });
        match &self.enhancer {
            None if iterations > 0 => Err(Error::invalid(
                "--refine",
                format!("0 without --enhancer DIR (found {iterations}: refinement needs an enhancer)"),
            )),
            Some(dir) if iterations > 0 => {
                check_enhancer_dir(dir, quiet)?;
                Ok(iterations)
            }
            _ => Ok(iterations),
        }
    }

    /// Refines `geometry` (reconstructed from `views`) `iterations` times at `--refine-size`,
    /// the enhancer's IP-Adapter seeing `input` when given; `None` when `iterations` is 0.
    pub fn refine(
        &self,
        geometry: &Mesh,
        views: &ViewSet,
        input: Option<&wonder3d::Image>,
        iterations: usize,
        texture: TextureOptions,
        quiet: bool,
    ) -> Result<Option<Refined>> {
        let Some(dir) = self.enhancer.as_ref().filter(|_| iterations > 0) else {
            return Ok(None);
        };
        let enhancer = diffusion_enhancer(dir, input, None, quiet)?;
        let options =
            RefineOptions::default().with_iterations(iterations).with_size(self.refine_size).with_texture(texture);
        refine_with_bar(geometry, views, enhancer.as_ref(), &options, quiet).map(Some)
    }
}

/// Fails naming the first missing file of an enhancer directory (of the snapshot of a Hub id,
/// downloaded first).
#[cfg(feature = "diffusion")]
fn check_enhancer_dir(dir: &std::path::Path, quiet: bool) -> Result<()> {
    let dir = enhancer_dir(dir, quiet)?;
    wonder3d::diffusion::pipelines::enhancer::check_enhancer_dir(&dir)
}

/// The diffusion enhancer needs the model (this binary has none).
#[cfg(not(feature = "diffusion"))]
fn check_enhancer_dir(_: &std::path::Path, _: bool) -> Result<()> {
    Err(crate::generate::without_model())
}

/// The enhancer folder of `--enhancer`: the folder itself, or the Hub id's snapshot in the
/// Hugging Face cache (downloaded first where it lacks files, with a bar unless `quiet`).
#[cfg(feature = "diffusion")]
fn enhancer_dir(dir: &std::path::Path, quiet: bool) -> Result<PathBuf> {
    let bar = progress::download_bar(quiet);
    let dir = crate::weights::resolve("--enhancer", dir, wonder3d::weights::Layout::Enhancer, &bar);
    bar.finish_and_clear();
    dir
}

/// The diffusion enhancer of `dir`, with the accelerations of `acceleration` (none without):
/// checked, and bf16 products this CPU lacks named in one line on stderr, before the weights
/// load.
#[cfg(feature = "diffusion")]
fn diffusion_enhancer(
    dir: &std::path::Path,
    input: Option<&wonder3d::Image>,
    acceleration: Option<&AccelerationArgs>,
    quiet: bool,
) -> Result<Box<dyn Enhancer>> {
    let acceleration = match acceleration {
        Some(args) => {
            let (acceleration, note) = args.acceleration()?;
            if let Some(note) = note {
                eprintln!("note: {note}");
            }
            acceleration
        }
        None => wonder3d::Acceleration::default(),
    };
    let dir = enhancer_dir(dir, quiet)?;
    let enhancer = wonder3d::refine::DiffusionEnhancer::load(&dir)?.with_acceleration(acceleration);
    Ok(Box::new(match input {
        Some(image) => enhancer.with_input_image(image.clone()),
        None => enhancer,
    }))
}

/// The diffusion enhancer needs the model (this binary has none).
#[cfg(not(feature = "diffusion"))]
fn diffusion_enhancer(
    _: &std::path::Path,
    _: Option<&wonder3d::Image>,
    _: Option<&AccelerationArgs>,
    _: bool,
) -> Result<Box<dyn Enhancer>> {
    Err(crate::generate::without_model())
}
