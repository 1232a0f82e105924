//! `wonder3d`: the command-line face of wonder3d-rs.
//!
//! ```text
//! wonder3d info assets/spot.obj          # counts, bbox, watertight, components, genus
//! wonder3d info assets/spot.obj --json   # the same as one JSON object
//! wonder3d render assets/spot.obj --rig wonder3d-ortho --size 256 --out views/spot
//! wonder3d reconstruct views/spot --out spot.glb --report report.json  # init + coarse
//! wonder3d eval spot.glb assets/spot.obj --json  # chamfer, fscore_0.01, iou_64, …
//! wonder3d texture assets/spot.obj views/spot --normalize --out spot.glb  # uv atlas + baked texture
//! wonder3d refine spot.glb views/spot --enhancer oracle:assets/spot.obj --out refined.glb  # enhance -> refine, 2 iterations
//! wonder3d demo --out demo                     # the whole pipeline on the bundled spot
//! wonder3d prepare mug.jpg --out mug.png --mask-out mask.png  # photo -> framed RGBA (background removed)
//! wonder3d generate cup.jpg --weights ckpts --out views/cup  # 6 views x {normal, colour} (docs/weights.md)
//! wonder3d run cup.jpg --weights ckpts --out cup.glb          # prepare -> generate -> reconstruct -> texture
//! wonder3d run cup.jpg --weights flamehaze1115/Wonder3D_plus --out cup.glb  # weights by Hub id, downloaded once (docs/weights.md)
//! wonder3d batch items.txt --out results --jobs 2 [--weights ckpts] [--shard 0/8] [--resume]  # many objects
//! wonder3d dataset assets/spot.obj assets/torus.obj --out train --samples 4 --size 256  # a training set (docs/training.md)
//! wonder3d train --stage 2 --data train --init model --out run2 --steps 1000  # train the multi-view UNet
//! ```

// Layers, bottom-up: each group imports only from itself and the groups above it.
// Shared argument parsers, progress bars, model folders by path or Hub id.
mod args;
mod progress;
#[cfg(feature = "diffusion")]
mod weights;

// Commands that others build on, each on the one before: prepare (photo → RGBA), generate
// (the model's options and loading), refine (enhancers and the refinement loop).
mod prepare;
//
mod generate;
//
mod refine;

// The other commands.
mod batch;
mod dataset;
mod demo;
mod eval;
mod info;
mod reconstruct;
mod render;
mod run;
mod texture;
mod train;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "wonder3d", version, about = "One photo in, a textured watertight 3D mesh out (Wonder3D++ in Rust).")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print a mesh's counts, bounding box and topology (merged by position).
    Info(info::InfoArgs),
    /// Render oracle views of a mesh (normals, colours, masks, depth, cameras.json).
    Render(render::RenderArgs),
    /// Compare a predicted mesh with a ground truth (Chamfer, F-score, volume IoU, normals).
    Eval(eval::EvalArgs),
    /// Reconstruct a closed mesh from a view-set folder (normal maps + masks).
    Reconstruct(reconstruct::ReconstructArgs),
    /// Texture a mesh from colour views: uv atlas, baked texture, GLB or OBJ out.
    Texture(texture::TextureArgs),
    /// Refine a reconstructed mesh and its texture against enhanced views (enhance → refine mesh → refine texture).
    Refine(refine::RefineArgs),
    /// The whole pipeline on the bundled spot, no downloads: views → mesh → texture → GLB + report.
    Demo(demo::DemoArgs),
    /// A photo or RGBA image → the model's input: background removed (with a confidence score), cropped and centred.
    Prepare(prepare::PrepareArgs),
    /// Generate 6 normal + 6 colour views of a photo or RGBA image with the multi-view diffusion model.
    Generate(generate::GenerateArgs),
    /// One image to a textured mesh: generate → reconstruct → texture.
    Run(run::RunArgs),
    /// Many objects: a manifest of images or view folders, one output folder each, resumable, shardable (Slurm, Kubernetes).
    Batch(batch::BatchArgs),
    /// A training set rendered from meshes: random rotations, camera types and backgrounds, one view-set folder per sample + dataset.json.
    Dataset(dataset::DatasetArgs),
    /// Train the multi-view UNet on a training set, one Wonder3D++ stage at a time; resumable.
    Train(train::TrainArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Info(args) => info::run(&args),
        Command::Render(args) => render::run(&args),
        Command::Eval(args) => eval::run(&args),
        Command::Reconstruct(args) => reconstruct::run(&args),
        Command::Texture(args) => texture::run(&args),
        Command::Refine(args) => refine::run(&args),
        Command::Demo(args) => demo::run(&args),
        Command::Prepare(args) => prepare::run(&args),
        Command::Generate(args) => generate::run(&args),
        Command::Train(args) => train::run(&args),
        Command::Run(args) => run::run(&args),
        Command::Batch(args) => batch::run(&args),
        Command::Dataset(args) => dataset::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
