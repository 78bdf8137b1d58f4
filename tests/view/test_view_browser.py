"""The browser the live view's tests drive: the system chromium runs scripts headless."""


def test_system_chromium_runs_scripts(page, tmp_path):
    page.set_content("<p id=out>static</p><script>document.getElementById('out').textContent = "
                     "String(6 * 7)</script>")
    assert page.inner_text("#out") == "42"
    page.screenshot(path=str(tmp_path / "smoke.png"))
    assert (tmp_path / "smoke.png").stat().st_size > 0
