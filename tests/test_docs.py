"""The documentation site (mkdocs.yml, docs/) and the README landing page.

(a) `mkdocs build --strict` succeeds: no broken link, anchor or reference, every page in the nav;
(b) README.md is a landing page (at most 150 lines) holding the two set-up commands verbatim;
(c) every relative link of README.md and of docs/**/*.md points to a file that exists;
(d) nothing the README held before the site was lost: its section headings are the docs'
    headings, its commands are in the docs, every `galileo` command has a section in
    docs/cli.md and every flag of every command is documented there.
"""
import contextlib
import importlib.util
import io
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"
SETUP_COMMANDS = ("pip install torch==2.13.0 -e . && python app.py",
                  "pip install torch==2.13.0 -e '.[test]' && python -m pytest")
README_MAX_LINES = 150

# the section headings of the README before the site (issue 31): each is a heading of a docs page
README_HEADINGS = (
    "Architecture", "Adding a scenario", "Problems over several videos", "Set-up: the two commands", "The app",
    "Command line", "`galileo simulate`", "`galileo dataset`", "`galileo scene`: a scene file for your own video",
    "`galileo track`", "`galileo infer`", "`galileo predict`", "`galileo calibrate`", "`galileo scenarios`",
    "`galileo experiment`", "`galileo report`", "`galileo infer` over a folder of videos",
    "Recognition: physical properties from one frame (Galileo section 4)", "The splash scenario (Physics 101)",
    "The spring scenario (Physics 101)", "The fall scenario (Physics 101)", "The world", "Materials", "File formats",
    "Scene file (`scene.json`)", 'Trajectory (`galileo simulate` output, `truth.json["trajectory"]`)',
    "Tracks (`galileo track` output)", "Inference result (`galileo infer` output)",
    "Recognition model (`galileo recognize train` output)",
    "Session folder (`sessions/<YYYYmmdd-HHMMSS>-<name>/`)", "Dataset folder", "Benchmarks",
)

# every command line of the README's examples before the site (its comments left out): each is in the docs
README_COMMANDS = (
    'pip install torch==2.13.0 -e . && python app.py',
    "pip install torch==2.13.0 -e '.[test]' && python -m pytest",
    'ONEDNN_MAX_CPU_ISA=AVX2 ATEN_CPU_CAPABILITY=avx2 OPENBLAS_CORETYPE=Haswell NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL" OPENCV_CPU_DISABLE=AVX512-SKX python -m pytest',
    'stress-ng --cpu 4 & python -m pytest; kill %1',
    'python app.py',
    'python app.py --scenario splash',
    'python app.py --video my.mp4 --scene my_scene.json [--name NAME]',
    'python app.py --video a.mp4 b.mp4 --scene a.json b.json --share k1 [--fix m2_kg=0.15]',
    'python app.py --scenario fall',
    'python app.py --upload [--scenario splash|spring|fall] [--name NAME]',
    'python app.py --session sessions/20261122-004500-demo',
    'python app.py --host 0.0.0.0 --port 8080',
    'python app.py --rerun off | save | web | connect rerun+http://127.0.0.1:9876/proxy',
    'python app.py --rerun web --rerun-web-port 9090 --rerun-grpc-port 9876',
    'python app.py --chains N --sweeps 75 --seed 0 --workers 2',
    'python app.py --init recognition [--model lenet.npz]',
    'python app.py --moves default | paper | fitted',
    'python app.py [--until-rhat 1.01] [--min-ess 400] [--max-sweeps 1500]',
    'python app.py --sweeps 75',
    'galileo simulate --scene scene.json [--set NAME=VALUE ...] [--frames N | --duration-s T] [--fps F] --out traj.json',
    'galileo simulate --scenario ramp --set angle_deg=20 --set k1=0.2 --set m1_kg=0.5 --duration-s 1.0 --out traj.json',
    'galileo dataset [--scenario ramp|splash|spring|fall] --preset demo|small|full|... --out DIR [--camera NAME] [--seed N]',
    'galileo scene VIDEO [--scenario ramp|splash|spring|fall] --points "u,v u,v ..." [--NUMBER VALUE ...] --out scene.json',
    'galileo scene VIDEO --points "u,v u,v u,v u,v" [--upper-at-m D] --ramp-length-m L --ramp-width-m W --angle-deg A',
    'galileo scene VIDEO --scenario splash --points "u,v u,v u,v u,v u,v u,v" --tank-width-m W --tank-depth-m D',
    'galileo scene VIDEO --scenario spring --points "u,v u,v u,v u,v" [--length-m L] [--object ID] [--spring ID]',
    'galileo scene VIDEO --scenario fall --points "u,v u,v u,v u,v" --length-m L --width-m W [--focal-px F]',
    'galileo track VIDEO --scene scene.json --out tracks.json [--debug-video overlay.mp4] [--quiet]',
    'galileo infer VIDEO [VIDEO ...] --scene scene.json [scene.json ...] [--tracks tracks.json ...]',
    'galileo infer slide20.mp4 slide10.mp4 --scene slide20.json slide10.json --share k1 --out both.json',
    'galileo infer slide20.mp4 --scene slide20.json --fix m2_kg=0.15 --out m1.json',
    'galileo predict --result result.json [--angle-deg 10] [--target-outcome | --scene other_scene.json] [--out answers.json]',
    'galileo calibrate --n 200 --scenes default|dataset|SCENE.json --out DIR [--sweeps 200 --chains 4 --draws 99',
    'galileo calibrate --videos DATASET --out DIR [--sweeps 200 --chains 4]',
    'galileo scenarios [--json]',
    'galileo experiment DATASET_DIR --out RESULTS_DIR [--chains N --sweeps 75 --seed 0] [--moves default|paper|fitted]',
    'galileo report RESULTS_DIR/results.parquet --out DIR [--recognition EVAL_DIR]',
    'galileo infer VIDEOS_DIR --scene scene.json --out RESULTS_DIR [flags of galileo infer] [--workers N | --scheduler ADDR | --slurm FILE]',
    'galileo infer DATASET_DIR --out RESULTS_DIR',
    'galileo dataset --preset full --out DS',
    'galileo recognize label --dataset DS',
    'galileo recognize train --dataset DS --labels galileo --out lenet.npz',
    'galileo recognize eval --dataset DS --out fig3/',
    'galileo recognize eval --dataset DS --model lenet.npz --out eval/',
    'galileo recognize predict VIDEO --scene scene.json [--model lenet.npz]',
    'galileo infer VIDEO --scene scene.json --init recognition [--model lenet.npz] [--recognition-move 5] --out result.json',
    'python app.py --init recognition',
    'galileo dataset --scenario splash --preset demo|small|full|looks|looks-small --out DIR',
    'galileo track DIR/demo/video.mp4 --scene DIR/demo/scene.json --out tracks.json',
    'galileo infer DIR/demo/video.mp4 --scene DIR/demo/scene.json --out result.json',
    'galileo experiment DIR --out RESULTS_DIR',
    'galileo scene ref.mp4 --scenario spring --points "u,v u,v u,v u,v" --object ref --spring loose --out ref.json',
    'galileo scene obj.mp4 --scenario spring --points "u,v u,v u,v u,v" --object obj --spring loose --out obj.json',
    'galileo infer ref.mp4 obj.mp4 --scene ref.json obj.json --fix m_ref_kg=0.1103 --out result.json',
    'python app.py --video ref.mp4 obj.mp4 --scene ref.json obj.json --fix m_ref_kg=0.1103',
    'galileo dataset --scenario spring --preset demo|small|full --out DIR',
    'galileo scene drop1.mp4 --scenario fall --points "u,v u,v u,v u,v" --length-m 0.91 --width-m 0.76 --object block --surface table --out drop1.json',
    'galileo scene drop2.mp4 --scenario fall --points "u,v u,v u,v u,v" --length-m 0.91 --width-m 0.76 --object block --surface table --out drop2.json',
    'galileo infer drop1.mp4 --scene drop1.json --out one.json',
    'galileo infer drop1.mp4 drop2.mp4 --scene drop1.json drop2.json --out both.json',
    'python app.py --video drop1.mp4 --scene drop1.json',
    'galileo dataset --scenario fall --preset demo|small|full --out DIR',
)

# facts and file-format fields the README held: each is in the docs, word for word
README_FACTS = (
    # file formats: the scene file's, the splash scene's and the session folder's fields
    "`ramp.angle_deg`", "`unit_m`, `start_units`", "`objects[0]`", "`objects[1]`", "`release_m`", "`release_s`",
    "`push_mps`", "`log_volume_factor`", "`yaw_deg`", "`settings.json`", "`events.json`", "`chains.json`",
    "`record.npz`", "`session.rrd`", "`.lock`",
    # result.json and the sample record
    "`posterior_derived`", "`not_identified`", "`map_at_prior_edge`", "`sweeps_to_map_1nat`", "`proposal_early_stop`",
    "`proposal_width`", "`samples_file`",
    # datasets, experiments, clusters
    ".galileo-dataset.json", "labels.galileo.json", "`job_extra_directives`", "`local_directory`",
    "`worker.rss_mb`", "`truth.log_mass_ratio`", "`mass_ratio_spearman`",
    # the paper's figures and the measured ones
    "Spearman (the paper: 0.52)", "the paper: at chance, Pearson 0.20", "the seed: r = 0.85 over 33 of 36 objects",
    "Galileo labels MSE 0.039, r 0.39 (the paper: 0.052, 0.44)",
    # the app
    "Uploads are capped at **500 MB**", "`chains/<i>/loglik`", "`galileo: warning: an inference worker died during sweep N",
)

LINK = re.compile(r"!?\[[^\]]*\]\(([^()\s]+)(?:\s+\"[^\"]*\")?\)")


def markdown_files() -> list[Path]:
    return [README, *sorted(DOCS.rglob("*.md"))]


def docs_text() -> str:
    return "\n".join(p.read_text(encoding="utf-8") for p in sorted(DOCS.rglob("*.md")))


def squash(text: str) -> str:
    return re.sub(r"\s+", " ", text)


def relative_links(path: Path) -> list[str]:
    """The relative link targets of a Markdown file (code blocks and spans left out)."""
    text = re.sub(r"(?ms)^\s*(```|~~~).*?^\s*\1", "", path.read_text(encoding="utf-8"))
    text = re.sub(r"`[^`\n]*`", "", text)
    out = []
    for target in LINK.findall(text):
        if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target) or target.startswith(("#", "/")):
            continue
        out.append(target)
    return out


def broken_links(path: Path) -> list[str]:
    """The relative links of a Markdown file whose file (or folder) does not exist."""
    return [t for t in relative_links(path) if not (path.parent / t.partition("#")[0]).exists()]


def headings(text: str) -> set[str]:
    text = re.sub(r"(?ms)^```.*?^```", "", text)
    return {h.strip() for h in re.findall(r"(?m)^#{1,6} (.+?)\s*$", text)}


def galileo_help(*argv: str) -> str:
    """`galileo ARGV --help`, as printed."""
    from galileo.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        try:
            main([*argv, "--help"])
        except SystemExit:
            pass
    return out.getvalue()


def subcommands(help_text: str) -> list[str]:
    """The subcommands an argparse help lists under its positional argument (COMMAND, STEP)."""
    listed = help_text.split("positional arguments:", 1)[1].split("options:", 1)[0]
    return re.findall(r"(?m)^    ([a-z][a-z0-9-]*)(?=\s|$)", listed)


def flags(help_text: str) -> set[str]:
    return set(re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", help_text)) - {"--help"}


# -- (a) the site builds, strictly ------------------------------------------------------------------

@pytest.mark.timeout(600)
def test_the_site_builds_strictly(tmp_path):
    missing = [m for m in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers")
               if importlib.util.find_spec(m) is None]
    if missing:
        pytest.skip(f"the documentation tools are not installed ({', '.join(missing)}): pip install -e '.[test]'")
    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)], cwd=ROOT,
                         env=env, capture_output=True, text=True, timeout=540)
    log = run.stdout + run.stderr
    assert run.returncode == 0, f"mkdocs build --strict failed:\n{log[-6000:]}"
    assert not re.search(r"(?m)^WARNING", log), log[-6000:]
    # mkdocstrings rendered the API reference from the docstrings
    api = (site / "api" / "index.html").read_text(encoding="utf-8")
    for name in ("galileo.api.infer", "galileo.api.Result", "galileo.inferencedata.to_datatree"):
        assert f'id="{name}"' in api, f"{name} is missing from the API reference"
    # links to repository files (BENCHMARKS.md, the notebooks) work in the site too
    assert (site / "repo" / "BENCHMARKS" / "index.html").is_file()
    for notebook in re.findall(r"\]\(\.\./(examples/[^)]+\.py)\)", (DOCS / "examples.md").read_text()):
        assert (site / "repo" / notebook).is_file(), notebook


# -- (b) the README is a landing page -------------------------------------------------------------

def test_readme_is_a_landing_page_with_the_two_set_up_commands():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= README_MAX_LINES, f"README.md has {len(text.splitlines())} lines"
    lines = [line.strip() for line in text.splitlines()]
    for command in SETUP_COMMANDS:
        assert command in lines, f"the set-up command {command!r} is not in README.md as it was"
    assert "## Set-up: the two commands" in lines
    assert "CI runs `bash .ci/run`, which installs everything and then runs the test command above." in lines
    assert "stress-ng --cpu 4 & python -m pytest; kill %1" in lines
    assert "docs/images/app.png" in text and (DOCS / "images" / "app.png").stat().st_size > 50_000
    for step in ("mkdocs serve", "mkdocs build --strict", "pip install -e '.[test]'"):
        assert step in text, f"README.md does not say how to build the docs: {step!r}"
    for command in ("galileo dataset", "galileo track", "galileo infer", "galileo predict", "galileo.infer(",
                    ".to_arviz()"):
        assert command in text


# -- (c) relative links point to files that exist --------------------------------------------------

@pytest.mark.parametrize("path", markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_points_to_a_file(path):
    assert not broken_links(path), f"{path.relative_to(ROOT)}: broken links {broken_links(path)}"


def test_the_link_check_finds_a_missing_page(tmp_path):
    page = tmp_path / "page.md"
    (tmp_path / "there.md").write_text("# There\n")
    page.write_text("[ok](there.md#there) [gone](missing.md) ![img](images/none.png) [web](https://example.org) "
                    "[anchor](#here) `[code](nope.md)`\n```\n[block](nope.md)\n```\n")
    assert broken_links(page) == ["missing.md", "images/none.png"]


def test_the_readme_links_into_the_site():
    targets = {t.partition("#")[0] for t in relative_links(README)}
    for page in ("docs/getting-started.md", "docs/cli.md", "docs/api.md", "docs/examples.md", "docs/app.md",
                 "docs/formats.md", "docs/cluster.md", "docs/add-a-scenario.md", "docs/benchmarks.md",
                 "docs/scenarios/ramp.md", "docs/scenarios/splash.md", "docs/scenarios/spring.md",
                 "docs/scenarios/fall.md"):
        assert page in targets, f"README.md does not link to {page}"


# -- (d) nothing of the README was lost; the command line is documented -----------------------------

def test_every_readme_section_is_a_docs_heading():
    found = headings(docs_text())
    lost = [h for h in README_HEADINGS if h not in found]
    assert not lost, f"README sections with no heading in docs/: {lost}"


def test_every_readme_command_is_in_the_docs():
    text = squash(docs_text())
    lost = [c for c in README_COMMANDS if squash(c) not in text]
    assert not lost, f"README commands missing from docs/: {lost}"


def test_the_readme_facts_and_fields_are_in_the_docs():
    text = squash(docs_text())
    lost = [f for f in README_FACTS if squash(f) not in text]
    assert not lost, f"missing from docs/: {lost}"


def test_every_galileo_command_has_a_section_and_every_flag_is_documented():
    cli = (DOCS / "cli.md").read_text(encoding="utf-8")
    sections = headings(cli)
    commands = subcommands(galileo_help())
    assert {"infer", "track", "dataset", "experiment"} <= set(commands), commands
    for flag in flags(galileo_help()):
        assert flag in cli, f"galileo {flag} is not in docs/cli.md"
    undocumented = {}
    for command in commands:
        assert any(h.startswith(f"`galileo {command}`") for h in sections), \
            f"docs/cli.md has no section for `galileo {command}`"
        text = galileo_help(command)
        steps = subcommands(text) if command == "recognize" else []
        for step in [None, *steps]:
            shown = text if step is None else galileo_help(command, step)
            missing = sorted(f for f in flags(shown) if f not in cli)
            if missing:
                undocumented[f"galileo {command}{'' if step is None else ' ' + step}"] = missing
    assert not undocumented, f"flags not in docs/cli.md: {undocumented}"
