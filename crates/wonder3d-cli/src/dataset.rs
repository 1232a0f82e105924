//! `wonder3d dataset MESHES… --out DIR [--samples N] [--size PX] [--seed S] [--camera
//! ortho|persp|both]`: a training set rendered from meshes (`docs/training.md`).

use std::path::PathBuf;

use wonder3d::Result;
use wonder3d::dataset::{CameraKind, Dataset, DatasetOptions, check_dataset_dir};

/// `--camera` of `wonder3d dataset`: one camera type for every sample, or both.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DatasetCameraArg {
    /// Orthographic views only (the `wonder3d-ortho` rig).
    Ortho,
    /// Perspective views only (the `wonder3d-persp` rig).
    Persp,
    /// Orthographic or perspective with p = 0.5 per sample.
    Both,
}

/// Arguments of `wonder3d dataset`.
#[derive(clap::Args)]
pub struct DatasetArgs {
    /// Mesh files (.obj, .ply, .glb, .gltf); their file names (stems) name the samples and
    /// must differ.
    #[arg(required = true)]
    meshes: Vec<PathBuf>,
    /// Output folder: a new or empty folder, or an earlier dataset, which is replaced once
    /// the new one is complete (a failure leaves it as it was).
    #[arg(long)]
    out: PathBuf,
    /// Samples (random rotations, camera types, backgrounds) per mesh.
    #[arg(long, default_value_t = DatasetOptions::default().samples, allow_hyphen_values = true, value_parser = crate::args::dataset_samples)]
    samples: usize,
    /// Image width and height in pixels.
    #[arg(long, default_value_t = DatasetOptions::default().size, allow_hyphen_values = true, value_parser = crate::args::dataset_size)]
    size: u32,
    /// Seed of every random choice: the same seed writes the same bytes.
    #[arg(long, default_value_t = 0, allow_hyphen_values = true, value_parser = crate::args::seed)]
    seed: u64,
    /// Camera type of the samples.
    #[arg(long, value_enum, default_value_t = DatasetCameraArg::Both)]
    camera: DatasetCameraArg,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

/// Runs `wonder3d dataset`.
pub fn run(args: &DatasetArgs) -> Result<()> {
    wonder3d::outputs::for_flag("--out", check_dataset_dir(&args.out))?;
    let camera = match args.camera {
        DatasetCameraArg::Ortho => Some(CameraKind::Ortho),
        DatasetCameraArg::Persp => Some(CameraKind::Persp),
        DatasetCameraArg::Both => None,
    };
    let options = DatasetOptions::default()
        .with_samples(args.samples)
        .with_size(args.size)
        .with_seed(args.seed)
        .with_camera(camera);
    // Every mesh is loaded and checked before anything renders.
    let dataset = Dataset::prepare(&args.meshes, &options)?;
    for object in dataset.objects().iter().filter(|o| o.flipped_outward) {
        eprintln!(
            "note: {} is a closed mesh wound inward (negative volume); using it flipped outward",
            object.source.display()
        );
    }
    let bar = crate::progress::bar(args.quiet)?;
    let manifest = dataset.write(&args.out, &mut crate::progress::follow(&bar))?;
    bar.finish_and_clear();
    println!(
        "wrote {} samples of {} meshes ({}×{}, seed {}) to {}",
        manifest.samples.len(),
        dataset.objects().len(),
        manifest.size,
        manifest.size,
        manifest.seed,
        args.out.display()
    );
    Ok(())
}
