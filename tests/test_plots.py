"""Plot helpers: colours stay with a series name across the panels of one figure."""

from miktcli.stats.plots import png_panels, series_colors, series_linestyles


def test_a_name_keeps_its_colour_in_every_panel():
    palette = ["c0", "c1", "c2"]
    panels = [{"mikt": [], "vpg": [], "mlpp": []}, {"vpg": []}, {"mlpp": [], "mikt": []}]
    colors = series_colors(panels, palette)
    assert colors == {"mikt": "c0", "vpg": "c1", "mlpp": "c2"}


def test_more_names_than_colours_wrap_around():
    colors = series_colors([{"a": [], "b": [], "c": []}], ["x", "y"])
    assert colors == {"a": "x", "b": "y", "c": "x"}


def test_summary_figure_with_a_panel_lacking_the_first_method(tmp_path):
    curve = [(0.0, 1.0), (1.0, 2.0)]
    out = png_panels([({"mikt": curve, "vpg": curve}, "pair one", {"vpg": [(0.0, 0.5, 1.5), (1.0, 1.5, 2.5)]}),
                      ({"vpg": curve}, "pair two", None)], tmp_path / "summary.png", "return")
    assert out.read_bytes().startswith(b"\x89PNG")


def test_the_given_order_comes_first_even_when_a_panel_lacks_it():
    colors = series_colors([{"vpg": []}], ["c0", "c1", "c2"], order=["mikt", "vpg", "mlpp"])
    assert colors["vpg"] == "c1"


def test_a_legend_can_say_more_than_the_name_while_the_colour_stays_the_names():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from miktcli.stats.plots import _draw

    curve = [(0.0, 1.0), (1.0, 2.0)]
    fig, ax = plt.subplots()
    try:
        _draw(ax, {"mikt": curve, "mlpp": curve}, "pair", "return", None, {"mikt": "C0", "mlpp": "C1"},
              {"mlpp": "mlpp (1 of 5 seeds)"})
        assert [t.get_text() for t in ax.get_legend().get_texts()] == ["mikt", "mlpp (1 of 5 seeds)"]
        assert [line.get_color() for line in ax.lines] == ["C0", "C1"]
    finally:
        plt.close(fig)


def test_only_curves_of_fewer_seeds_than_the_grid_are_labelled_with_their_count():
    from miktcli.studies.summary import partial_seed_labels

    assert partial_seed_labels({"mikt": 5, "vpg": 5, "mlpp": 1}, 5) == {"mlpp": "mlpp (1 of 5 seeds)"}
    assert partial_seed_labels({"mikt": 1}, 1) == {}
    # seeds planned curve by curve (a pair's own seeds): three of three is whole, three of five is not
    assert partial_seed_labels({"mikt": 3, "vpg": 3}, {"mikt": 3, "vpg": 5}) == {"vpg": "vpg (3 of 5 seeds)"}


def test_more_curves_than_colours_change_line_style_so_no_two_curves_look_alike():
    names = [f"w{i}" for i in range(12)]
    colors = series_colors([dict.fromkeys(names, [])], ["c0", "c1", "c2", "c3", "c4"])
    styles = series_linestyles(colors, 5)
    looks = {(colors[n], styles[n]) for n in names}
    assert len(looks) == 12 and styles["w0"] == "-" and styles["w5"] == "--" and styles["w10"] == ":"
