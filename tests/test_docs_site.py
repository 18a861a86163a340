"""The documentation site: references resolve, every public name is in the API reference with its docstring, the
worked example of docs/write-your-own-model.md meets the model contract, and the built pages render their figures
in a real browser (Chromium).

The built-site tests are slow-tier tests that read a site built beforehand (`mkdocs build --strict`, which .ci/run
does first): the folder `FRICJAX_DOCS_SITE` (default `build/site`). Without a built site or without Chromium they
skip, saying why; with `FRICJAX_DOCS_REQUIRE=1` (set by .ci/run) they fail instead.
"""

from __future__ import annotations

import html
import importlib.util
import inspect
import os
import pathlib
import re
import shutil
import sys

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np
import pytest

import fricjax as fj

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
HOOKS = DOCS / "_hooks"
REQUIRE = os.environ.get("FRICJAX_DOCS_REQUIRE") == "1"


def _unavailable(reason: str):
    if REQUIRE:
        pytest.fail(f"{reason} (FRICJAX_DOCS_REQUIRE=1: the documentation checks must run here)")
    pytest.skip(reason)


def _hook_module(name: str):
    if str(HOOKS) not in sys.path:
        sys.path.insert(0, str(HOOKS))
    return importlib.import_module(name)


def _public_identifiers() -> list[str]:
    api = _hook_module("api")
    names = [f"fricjax.{n}" for n in api.public_names(fj) if n not in api.NAMESPACES]
    for namespace in api.NAMESPACES:
        names += [f"fricjax.{namespace}.{n}" for n in api.public_names(getattr(fj, namespace))]
    return names


def _resolve(identifier: str):
    obj = fj
    for part in identifier.split(".")[1:]:
        obj = getattr(obj, part)
    return obj


# ---------------------------------------------------------------------------------------------------- fast tier


def test_every_paper_key_cited_in_the_sources_has_a_full_reference():
    links = _hook_module("links")
    sources = "\n".join(p.read_text() for p in (ROOT / "src" / "fricjax").rglob("*.py"))
    cited = set(re.findall(r"\b[a-z]+(?:19|20)\d\d\b", sources)) | {
        key for key in ("emps-ensemble", "kernel-method", "amthor") if key in sources
    }
    assert cited, "no paper key found in the sources: the pattern above is out of date"
    unknown = cited - set(links.PAPER_KEYS)
    assert not unknown, f"paper keys cited in src/ but not linked by docs/_hooks/links.py PAPER_KEYS: {unknown}"
    references = (DOCS / "references.md").read_text()
    missing = [key for key in links.PAPER_KEYS if "{#ref-" + key + "}" not in references]
    assert not missing, f"docs/references.md has no section with the anchor ref-KEY for {missing}"


def test_every_fj_name_the_sources_mention_exists():
    """A docstring naming `fj.NAME` that does not exist is a broken cross-reference on the site."""
    broken = set()
    for path in (ROOT / "src" / "fricjax").rglob("*.py"):
        for match in re.finditer(r"\bfj\.((?:compare|emps|boucwen)\.)?([A-Za-z_]\w*)", path.read_text()):
            namespace = getattr(fj, match.group(1)[:-1]) if match.group(1) else fj
            if not hasattr(namespace, match.group(2)):
                broken.add(f"{match.group(0)} ({path.relative_to(ROOT)})")
    assert not broken, sorted(broken)


def test_links_leave_code_alone_and_link_keys_and_public_names():
    links = _hook_module("links")
    public = frozenset({"fricjax.simulate", "fricjax.compare.score"})
    text = "worden2007 §3 and `fj.simulate`, `fj.compare.score`, `fj.nothing`, `worden2007`\n```\nworden2007\n```"
    out = links.link_markdown(text, public)
    assert out.startswith("[worden2007][ref-worden2007] §3 and [`fj.simulate`][fricjax.simulate], ")
    assert "[`fj.compare.score`][fricjax.compare.score]" in out
    assert "`fj.nothing`, `worden2007`\n```\nworden2007\n```" in out
    assert links.link_markdown("# worden2007 {#ref-worden2007}", public) == "# worden2007 {#ref-worden2007}"


def test_api_pages_place_every_public_name():
    pytest.importorskip("griffe", reason="the docs extra is not installed: pip install -e '.[docs]'")
    api = _hook_module("api")
    grouped = api.pages(str(ROOT / "src"))
    rendered = {entry.identifier for entries in grouped.values() for entry in entries}
    missing = sorted(set(_public_identifiers()) - rendered)
    assert not missing, f"public names on no API page: {missing}"
    for section, entries in grouped.items():
        markdown = api.page_markdown(str(ROOT / "src"), section, entries)
        for entry in entries:
            assert f"::: {entry.identifier}\n" in markdown


def _spring_slider_module():
    spec = importlib.util.spec_from_file_location("spring_slider", DOCS / "examples" / "spring_slider.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _motion(n: int = 300) -> fj.Motion:
    t = np.arange(n) * 1e-3
    return fj.Motion.from_position(2e-5 * np.sin(2 * np.pi * 2 * t) * (1 + 8 * t), dt=1e-3)


def test_the_site_builds_without_the_data_folder(monkeypatch, tmp_path):
    """A fresh clone without the shared data folder builds the site: the notebooks on real records become pages that
    say what to set (they raised "FRICJAX_DATA=... is no folder" and failed the build); the others run."""
    notebooks = _hook_module("notebooks")
    monkeypatch.setenv("FRICJAX_DATA", str(tmp_path / "absent"))
    paths = {p.stem: p for p in notebooks.NOTEBOOKS.glob("*.ipynb")}
    assert notebooks.missing_data(paths["01_emps"]) is not None
    assert "FRICJAX_DATA" in notebooks.execute(paths["07_damper_records"], log=lambda _: None)
    assert notebooks.missing_data(paths["02_fit_lugre_gms"]) is None  # synthetic records: it runs
    monkeypatch.setenv("FRICJAX_DATA", str(tmp_path))
    assert notebooks.missing_data(paths["01_emps"]) is None


def test_search_is_configured_to_work_from_a_file():
    """mkdocs-material's offline plugin (the search index inlined as search/search_index.js) with a local copy of the
    iframe-worker shim: browsers refuse Web Workers from file://, and the plugin would add the shim from unpkg.com
    (a network request) unless extra.polyfills names one already."""
    config = (ROOT / "mkdocs.yml").read_text()
    plugins = re.search(r"^plugins:\n((?:  .*\n)+)", config, re.M)
    assert plugins and re.search(r"^  - offline\b", plugins.group(1), re.M), "mkdocs.yml: no `- offline` plugin"
    polyfills = re.search(r"^  polyfills:\n((?:    - .*\n)+)", config, re.M)
    assert polyfills, "mkdocs.yml: no extra.polyfills (the offline plugin would load the shim from unpkg.com)"
    scripts = re.findall(r"^    - (\S+)", polyfills.group(1), re.M)
    assert scripts == ["javascripts/iframe-worker-shim.js"], scripts
    shim = (DOCS / scripts[0]).read_text()
    assert "window.Worker" in shim and "http" not in shim.split("*/", 1)[1]


@pytest.mark.slow  # about 15 s: several compilations of the example model
def test_write_your_own_model_example_meets_the_model_contract(tmp_path):
    """docs/examples/spring_slider.py through the battery's checks: step loop == simulate == no jit, vmap ==
    loop, finite-difference gradients of the smooth model, model files, exact physics of a spring-slider."""
    example = _spring_slider_module()
    model = example.SpringSlider(k=1e5, Fc=1.0, c=5.0)
    motion = _motion()
    force = fj.simulate(model, motion)
    assert force.shape == (motion.length,) and force.dtype == jnp.float64 and np.all(np.isfinite(force))

    # the physics: a spring below the slip force, saturated at +/- Fc above it (plus the viscous term)
    samples = motion.samples(model.requires)
    spring, expected = 0.0, []
    for k in range(motion.length):
        spring = float(np.clip(spring + 1e5 * float(samples.dx[k]), -1.0, 1.0))
        expected.append(spring + 5.0 * float(samples.v[k]))
    np.testing.assert_allclose(force, expected, rtol=1e-10, atol=1e-12)

    state, loop = model.init_state(), []
    for k in range(motion.length):
        state, y = model.step(state, samples.at(k))
        loop.append(y)
    np.testing.assert_allclose(loop, force, rtol=1e-10, atol=1e-12)
    with jax.disable_jit():
        np.testing.assert_allclose(fj.simulate(model, motion), force, rtol=1e-10, atol=1e-12)

    batch = [example.SpringSlider(k=k, Fc=f, c=1.0) for k, f in ((5e4, 0.5), (1e5, 1.0), (2e5, 2.0))]
    stacked = fj.stack_models(batch)
    vmapped = eqx.filter_vmap(lambda m: fj.simulate(m, motion))(stacked)
    np.testing.assert_allclose(vmapped, [fj.simulate(m, motion) for m in batch], rtol=1e-10, atol=1e-12)

    smooth = fj.with_smoothing(model, fj.Smooth(1e-2))
    target = force + 0.01 * np.cos(np.arange(motion.length))
    params, static = eqx.partition(smooth, fj.trainable_filter(smooth))

    def loss(p):
        return jnp.mean((fj.simulate(eqx.combine(p, static), motion) - target) ** 2)

    grads = jax.grad(loss)(params)
    leaves = jax.tree_util.tree_leaves(grads)
    assert leaves and all(np.all(np.isfinite(g)) for g in leaves)
    flat, unflatten = jax.flatten_util.ravel_pytree(params)
    direction = np.random.default_rng(0).standard_normal(flat.shape)
    h = 1e-6
    numeric = (loss(unflatten(flat + h * direction)) - loss(unflatten(flat - h * direction))) / (2 * h)
    analytic = float(jax.flatten_util.ravel_pytree(grads)[0] @ direction)
    np.testing.assert_allclose(analytic, float(numeric), rtol=1e-5)

    path = tmp_path / "spring_slider.eqx"
    fj.save_model(path, model)
    again = fj.load_model(path, classes=(example.SpringSlider, example.SpringSliderState))
    np.testing.assert_array_equal(fj.simulate(again, motion), force)


@pytest.mark.slow
def test_write_your_own_model_example_fits():
    example = _spring_slider_module()
    motion = _motion(1500)
    true = example.SpringSlider(k=1e5, Fc=1.0, c=5.0)
    data = fj.FrictionData(motion, fj.simulate(true, motion))
    start = example.SpringSlider(k=5e4, Fc=1.5, c=0.0, smoothing=fj.Smooth(1e-2))
    result = fj.fit(start, data, solver=fj.levenberg_marquardt(), steps=50, separable=("c",))
    fitted = fj.exact(result.model)
    assert float(fj.nmse(data.force, fj.simulate(fitted, motion))) < 0.05
    values = fj.unwrap(fitted)  # c is weakly excited (|v| ~ 1 mm/s): the stiffness and slip force are what count
    np.testing.assert_allclose([values.k, values.Fc], [1e5, 1.0], rtol=0.02)


# ------------------------------------------------------------------------------------------- the built site


@pytest.fixture(scope="module")
def site() -> pathlib.Path:
    folder = pathlib.Path(
        os.environ.get("FRICJAX_DOCS_SITE", ROOT / "build" / "site")
    ).resolve()  # a relative path from .ci/run
    if not (folder / "index.html").is_file():
        _unavailable(f"no built documentation site at {folder}: run `mkdocs build --strict` first")
    return folder


def _text(page: str) -> str:
    page = re.sub(r"<(script|style)\b.*?</\1>", " ", page, flags=re.S)
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", page)).split())


def _plain(markdown: str) -> str:
    markdown = re.sub(r"\[([^\]]*)\]\[[^\]]*\]", r"\1", markdown)  # [text][identifier] -> text
    markdown = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", markdown)
    return " ".join(markdown.replace("`", " ").replace("**", " ").split())


@pytest.mark.slow
def test_built_reference_holds_every_public_name_with_its_docstring(site):
    pages = {p.name: p.read_text() for p in (site / "api").glob("*.html")}
    texts = {name: _text(page) for name, page in pages.items()}
    missing, undocumented = [], []
    for identifier in _public_identifiers():
        holders = [name for name, page in pages.items() if f'id="{identifier}"' in page]
        if not holders:
            missing.append(identifier)
            continue
        obj = _resolve(identifier)
        if callable(obj) and not isinstance(obj, type(fj)):
            if not (inspect.getdoc(obj) or "").strip():
                undocumented.append(f"{identifier}: no docstring")
                continue
            summary = _plain(inspect.getdoc(obj).split("\n\n")[0])[:60]
            words = re.findall(r"[A-Za-z0-9]{4,}", summary)
            if not all(any(w in texts[h] for h in holders) for w in words):
                undocumented.append(f"{identifier}: {summary!r}")
    assert not missing, f"public names with no entry in the built API reference: {missing}"
    assert not undocumented, f"API entries without their docstring: {undocumented}"


@pytest.mark.slow
def test_built_pages_resolve_paper_keys_and_show_equations(site):
    references = (site / "references.html").read_text()
    for key in _hook_module("links").PAPER_KEYS:
        assert f'id="ref-{key}"' in references, key
    lugre = (site / "models" / "lugre.html").read_text()
    assert 'href="../references.html#ref-worden2007"' in lugre
    assert lugre.count("<math") >= 5 and "arithmatex" not in lugre  # MathML, no formula left as TeX


@pytest.mark.slow
def test_built_site_inlines_the_search_index_and_loads_no_script_from_the_network(site):
    index = (site / "search" / "search_index.js").read_text()
    assert index.startswith("var __index = {") and '"docs":' in index
    for path in (site / "index.html", site / "models" / "lugre.html"):
        page = path.read_text()
        assert "javascripts/iframe-worker-shim.js" in page, path.name
        remote = re.findall(r"<script[^>]+src=\"(https?:[^\"]+)\"", page)
        assert not remote and "unpkg.com" not in page, (path.name, remote)


def _chromium() -> str:
    path = os.environ.get("FRICJAX_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    if not path:
        _unavailable("Chromium is not installed (Debian: apt-get install chromium)")
    return path


@pytest.mark.slow
def test_notebook_pages_render_their_figures_in_chromium(site, tmp_path):
    """Open the built index and every notebook page in headless Chromium: each notebook page shows figures (every
    <img> decoded, naturalWidth > 0) and a screenshot of its first figure is not blank."""
    playwright = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (the docs extra)")
    from PIL import Image

    chromium = _chromium()
    shots = pathlib.Path(os.environ.get("FRICJAX_DOCS_SCREENSHOTS", tmp_path))
    shots.mkdir(parents=True, exist_ok=True)
    notebook_pages = sorted((site / "notebooks").glob("*.html"))
    assert len(notebook_pages) == len(list((ROOT / "notebooks").glob("*.ipynb"))), notebook_pages
    args = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update"]
    args += ["--disable-sync", "--no-first-run"]
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=args, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 1000})
            page.goto((site / "index.html").as_uri(), wait_until="load")
            assert page.title().startswith("fricjax")
            assert page.locator("nav.md-nav").count() > 0 and "fricjax" in page.locator("h1").first.inner_text()
            page.screenshot(path=str(shots / "index.png"))
            for path in notebook_pages:
                page.goto(path.as_uri(), wait_until="load")
                images = page.evaluate(
                    "Array.from(document.querySelectorAll('article img')).map("
                    "i => ({src: i.getAttribute('src'), complete: i.complete, width: i.naturalWidth}))"
                )
                assert images, f"{path.name}: no figure on the page"
                broken = [i for i in images if not (i["complete"] and i["width"] > 0)]
                assert not broken, f"{path.name}: figures that did not load: {broken}"
                figure = page.locator("article img.notebook-figure").first
                figure.scroll_into_view_if_needed()
                shot = shots / f"{path.stem}.png"
                figure.screenshot(path=str(shot))
                pixels = np.asarray(Image.open(shot).convert("L"), dtype=float)
                assert pixels.shape[0] > 50 and pixels.shape[1] > 50, (path.name, pixels.shape)
                assert pixels.std() > 5.0, f"{path.name}: the screenshot of its first figure is blank"
                page.screenshot(path=str(shots / f"{path.stem}-page.png"))
        finally:
            browser.close()


@pytest.mark.slow
def test_search_works_from_file_in_chromium(site):
    """Opened from disk with every network request refused, the search box finds a model page."""
    playwright = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (the docs extra)")
    chromium = _chromium()
    args = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update"]
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=args, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 1000})
            requests: list[str] = []
            page.route("http*://**", lambda route: (requests.append(route.request.url), route.abort()))
            errors: list[str] = []
            page.on("pageerror", lambda error: errors.append(str(error)))
            page.goto((site / "index.html").as_uri(), wait_until="load")
            box = page.locator("input.md-search__input")  # material hides it when its search worker fails
            box.wait_for(state="visible", timeout=15_000)
            box.click()
            box.press_sequentially("Maxwell", delay=20)  # keystrokes, as a reader types (fill() sends no keys)
            results = page.locator("li.md-search-result__item")
            results.first.wait_for(timeout=15_000)
            links = results.locator("a").evaluate_all("links => links.map(a => a.getAttribute('href'))")
            assert any("maxwell-slip" in (href or "") for href in links), links
            assert not requests, f"the site asked the network for {requests}"
            assert not errors, errors
        finally:
            browser.close()
