"""``trioman bench ablation``: the paper's Tables 1 and 2 on held-out synthetic subjects.

The Refiner (one per condition none / tex / tex+geo / warp / warp+geo) and the Examiner are trained on the corpus's
training subjects (``trioman synth-corpus``); the avatars are trained on the held-out subjects, which
those models never saw, and evaluated on their test split (novel poses from novel views).

Variants, per held-out subject (``VARIANTS``), all from the quick preset:

    baseline        real frames only, ``iterations`` steps (seeds 0 .. seeds-1)
    baseline_long   equal-compute control: real frames only, as many steps as an augmented run (seeds)
    G               + Generator: online pseudo-GT = the avatar's own coarse renders (--augment coarse)
    aligned         the render with real pixels carried through the body mesh, no learned model (--augment aligned)
    GR_none/tex/tex+geo   + Refiner under each of the paper's conditions (--augment refined)
    GR_warp+geo     + Refiner refining the aligned reference, with the normal map (conditions warp+geo)
    GRk_warp+geo    the same, keeping the carried real pixels: the Refiner's output only where nothing was carried
    GRE             + Refiner (warp+geo, carried pixels kept) & Examiner, best of 2 candidates (--augment examined; seeds)
    ceiling_seen    the truth only where a training frame saw the surface, unsupervised elsewhere on the body
                    (--augment truth_seen): what pseudo-GT made from the capture alone gives, with nothing invented
    ceiling         the truth at every draw: the subject's own renderer (--augment truth), what a perfect Refiner gives

Every augmented row is also reported as the share of the ceiling's gain over the control it recovers.
The plan's ``coverage`` and ``pose_noise`` re-render the held-out subjects with that share of the turn and
that fitting noise (OUT/subjects); with pose noise the avatars are evaluated at the true test poses. Its ``reach``
scales the Generator's camera sigmas (the augmented runs' folders say so; the unaugmented ones are shared).

With ``--detail-sigma S`` a lever (``LEVERS``) is trained too: GRd_tex+geo, the tex+geo Refiner's
pseudo-GT keeping only its detail (``--augment-detail-sigma S``, runtime.generator.keep_detail).

An augmented run takes ``iterations / (start + (1 - start) (1 - share))`` steps, so that it trains on
as many real frames as the baseline plus its pseudo-GT steps; ``baseline_long`` has that length.
A finished run (and its evaluation) is reused, so an interrupted benchmark resumes where it stopped. The runs of
one seed as long as an augmented run (the control and the augmented rows) fork from one shared real-frame warm-up,
the control's first ``start`` steps trained once (toolkit/train/fork.py: the same weights as from scratch, bit
for bit), so each trains that many steps fewer.

Also measured: whether the tex+geo and warp+geo Refiners use their conditions (held-out test triplets refined
with the true reference and normal map; with another subject's reference frame (tex+geo) or nothing carried,
the coarse render as the aligned reference (warp+geo); with a zero normal map).
Writes ablation.md / ablation.json, a bar chart per subject, one grid of the same test frames across
variants per subject, and the same Generator draws as pseudo-GT through each mode and Refiner.

The modules: ``plan`` (each row's training config, its runs, the models it needs, the jobs still to train), ``jobs``
(the cost model and the scheduler that trains them), ``models`` (the Refiners and the Examiner), ``subjects`` (the
held-out subjects of a capture regime), ``measure`` (evaluation, the condition check, pseudo-GT against the truth),
``report`` (the summary, the figures, the markdown) and ``bench`` (``bench_ablation``, the whole target).
"""

from trioman.bench.ablation.bench import bench_ablation
from trioman.bench.ablation.jobs import Job, train_in_parallel
from trioman.bench.ablation.measure import condition_check, pseudo_gt_truth
from trioman.bench.ablation.plan import needed_models
from trioman.bench.ablation.report import LABELS, ablation_markdown, summarise
from trioman.bench.ablation.subjects import regime_subject
from trioman.bench.ablation_config import AblationBenchConfig, AblationPlan

__all__ = ["LABELS", "AblationBenchConfig", "AblationPlan", "Job", "ablation_markdown", "bench_ablation", "condition_check",
           "needed_models", "pseudo_gt_truth", "regime_subject", "summarise", "train_in_parallel"]
