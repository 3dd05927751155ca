"""Fixtures of the augmented-training tests (test_augmentation.py, test_fork.py): a tiny synthetic subject, checkpoints
of a tiny Refiner and Examiner, two torch threads. A test module's own fixture of the same name wins over these. Torch
stays out of this module (the fixtures import it), so it collects without torch."""

import pytest

SIZE = 32  # the subject's side and the models' image size


@pytest.fixture(scope="module")
def subject(tmp_path_factory):
    from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject

    out = tmp_path_factory.mktemp("subj") / "s"
    synthesize_subject(SynthConfig(seed=5, size=SIZE, frames=10, texture_size=256), out, progress=False)
    return out


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """Checkpoints of a tiny tex+geo Refiner and a tiny Examiner, in refiner_loop/examiner_loop's format."""
    torch = pytest.importorskip("torch")
    from trioman.toolkit.examiner import Examiner, ExaminerConfig
    from trioman.toolkit.refiner import RefinerConfig, create_refiner

    d = tmp_path_factory.mktemp("models")
    refiner = create_refiner(RefinerConfig(image_size=SIZE, vae_widths=(8, 8, 8), unet_widths=(8, 16, 16), attention_heads=2,
                                           conditions="tex+geo"), seed=0)
    examiner = Examiner(ExaminerConfig(img_size=SIZE, patch_size=8, embed_dim=16, depth=1, num_heads=2, dual_dims=(8,),
                                       dual_heads=2, head_hidden=8))
    paths = {"refiner": d / "refiner.pt", "examiner": d / "examiner.pt"}
    for name, m in (("refiner", refiner), ("examiner", examiner)):
        torch.save({"step": 0, "model": m.state_dict(), "config": m.config.to_dict()}, paths[name])
    return paths


@pytest.fixture
def two_threads():
    # With two torch threads the CPU index backward used to accumulate in a thread-dependent order (resumed
    # and straight runs differed by up to 4e-4); train() now runs torch's deterministic kernels.
    torch = pytest.importorskip("torch")
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(threads)
