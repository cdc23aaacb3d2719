//! The paper's Figure 12: the in-between crowns of the sketch animation stay
//! closer to the reference crowns (the linear interpolation of the source
//! and target silhouettes along the correspondence) than those of a
//! topology-aware *morph* from the input tree to the sketched result.
//!
//! Both animations end at the same tree, so near t = 0 and t = 1 they
//! agree; the gap opens in between, where the morph interpolates chains in
//! their own frames (branches swing) while the sketch animation moves the
//! crown along the reference. Measured by the same foliage-outline Fréchet
//! distance at t = ¼, ½, ¾, over every preset and sketch.
//!
//! Since chains are re-solved with their rest segment lengths (the sketch
//! crate's `rigid` module), the sketched result keeps its branch lengths,
//! and a morph into it swings branches without stretching them: on some
//! sketches the two now tie (e.g. 0.0678 against 0.0677). A case counts
//! for the sketch animation when it is at most 5 % farther than the
//! morph; it must win 5 cases in 6, and its mean must stay 10 % below the
//! morph's (0.077 against 0.107 when this was written).

use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_generate::Preset;
use treemorph_morph::{MorphOptions, MorphPlan, Morpher};
use treemorph_sketch::{SketchMetrics, SketchOptions, SketchPlan, Sketcher};

use crate::{example, fixture};

#[test]
fn in_between_crowns_stay_closer_to_the_reference_than_a_morph() {
    let mut wins = 0;
    let mut cases = 0;
    let (mut ours_total, mut theirs_total) = (0.0f32, 0.0f32);
    for &preset in Preset::ALL {
        for sketch in ["heart", "diamond", "star"] {
            let f = fixture(preset);
            let file = example(sketch);
            let options = SketchOptions::default().with_fit(file.fit);
            let plan =
                SketchPlan::new(&f.tree, &f.analysis, &file.view, &file.sketch, &options).unwrap();
            let mut sketcher = Sketcher::new(&plan);
            let result = sketcher.result_tree(&f.tree).unwrap();
            let result_analysis = Analysis::of(&result, &AnalysisOptions::default()).unwrap();
            let morph = MorphPlan::new(
                &f.tree,
                &f.analysis,
                &result,
                &result_analysis,
                &MorphOptions::default(),
            )
            .unwrap();
            let mut morpher = Morpher::new(&morph);
            let mut morphed = morpher.new_frame();
            let mut metrics = SketchMetrics::new(&plan);
            let (mut ours, mut theirs) = (0.0f32, 0.0f32);
            for t in [0.25f32, 0.5, 0.75] {
                let frame = sketcher.frame(t);
                ours += metrics.shape(&frame).frechet_normalised / 3.0;
                morpher.morph(t, &mut morphed);
                morphed.t = t;
                theirs += metrics.shape(&morphed).frechet_normalised / 3.0;
            }
            println!("{preset} {sketch}: sketch {ours:.4}, morph {theirs:.4}");
            cases += 1;
            wins += usize::from(ours <= 1.05 * theirs);
            ours_total += ours;
            theirs_total += theirs;
        }
    }
    assert!(
        ours_total < 0.9 * theirs_total,
        "mean Fréchet: sketch {} vs morph {}",
        ours_total / cases as f32,
        theirs_total / cases as f32
    );
    assert!(
        wins * 6 >= cases * 5,
        "the sketch animation is closer in only {wins} of {cases} cases"
    );
}
