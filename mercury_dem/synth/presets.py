"""The three synthetic mission designs: ``tiny`` (tests), ``demo`` (make demo), ``large`` (clusters).

A :class:`MissionDesign` says where images go and how they look; the seed, the
pointing and position errors come from :class:`mercury_dem.config.synth.SynthConfig`.

Choices and reasons (also in docs/design/synth.md):

* ``tiny``: 256^2 images over lat -10..20, lon -15..15 (the area straddles the
  equator — the hemisphere and region boundary —, the 0/360 seam — a region
  boundary —, and 10-degree tile boundaries), four passes of 3 x 3 images plus
  two isolated ones (one near the north pole). 256 pixels at 1.1-3.2 km/pixel
  keeps it at ~40 images and well under 30 s to generate; scales 0.9-3.4 km
  (pairs up to ~3.8x apart).
* ``demo``: global, 512^2 at 1.2-3.2 km/pixel (median ~2 km), three passes
  laid on randomly rotated Fibonacci spirals so each point is seen >= 3x; one
  data gap (a 22-degree cap with a single isolated image, hence empty tiles).
  ~240 images, so generation stays within a few minutes on 2 cores and the
  whole pipeline within make demo's budget. Coarser than the reference's
  75-800 m/pixel on purpose (the reference needed 100,000 images). The NAC is
  allowed ranges up to 60,000 km (flyby-like) so both cameras take part.
* ``large``: the same design at 1024^2 and 70-300 m/pixel (NAC within
  15,000 km as in orbit): >10^4 images, generated in parallel on Dask.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mercury_dem.altimetry.simulate import AltimetryDesign
from mercury_dem.exceptions import ConfigError
from mercury_dem.synth.render import RenderSettings
from mercury_dem.synth.terrain import GTMES_PACKAGED, SurfaceParams, with_shape_harmonics


@dataclass(frozen=True)
class MissionDesign:
    """Where the images go and what they look like.

    area_deg : (lat_min, lat_max, lon_min, lon_max), longitudes may run through 0
        (``lon_min < 0``); None means the whole body
    samples : image size (square), pixels
    pixel_scale_m : (min, max) ground pixel scale at the image centre, drawn log-uniformly
    passes : number of coverage passes (each covers the area about once)
    spacing_factor : centre spacing / median footprint width within a pass
    nac_fraction : share of NAC images where the NAC can reach the pixel scale
    nac_max_slant_m : farthest NAC range (MESSENGER's apoapsis is ~15,000 km)
    incidence_deg, emission_deg : (min, max) at the image centre
    sun_campaigns : illumination per pass, cycled: (sun azimuth, azimuth jitter, incidence min,
        incidence max) in degrees; azimuth from local east towards north (0 = sun in the east,
        a morning campaign). Real imaging campaigns have consistent illumination at a site
        (the sun azimuth follows local time); uniformly random azimuths would leave most
        pairs unmatchable. Isolated images use the first campaign.
    isolated : extra images (lat, lon) placed apart from everything
    gaps : (lat, lon, radius_deg) caps where no pass puts an image (data gaps: empty
        tiles; an isolated image may sit in one)
    truth_dem_ppd : pixels per degree of the stored truth DEM
    altimetry : simulated MLA profiles of the truth (mercury_dem.altimetry.simulate), or None;
        drawn from their own random stream, so the images and the truth do not depend on it
    """

    name: str
    area_deg: tuple[float, float, float, float] | None
    samples: int
    pixel_scale_m: tuple[float, float]
    passes: int
    spacing_factor: float = 0.85
    nac_fraction: float = 0.5
    nac_max_slant_m: float = 15_000e3
    incidence_deg: tuple[float, float] = (20.0, 85.0)
    emission_deg: tuple[float, float] = (0.0, 45.0)
    sun_campaigns: tuple[tuple[float, float, float, float], ...] = (
        (0.0, 15.0, 25.0, 50.0),   # morning, moderate sun
        (10.0, 15.0, 55.0, 80.0),  # morning, low sun: long shadows (30 vs 70 deg pairs with the first)
        (-15.0, 15.0, 35.0, 60.0),
        (25.0, 15.0, 20.0, 45.0),
    )
    isolated: tuple[tuple[float, float], ...] = ()
    gaps: tuple[tuple[float, float, float], ...] = ()
    truth_dem_ppd: float = 4.0
    surface: SurfaceParams = field(default_factory=SurfaceParams)
    render: RenderSettings = field(default_factory=RenderSettings)
    altimetry: AltimetryDesign | None = None


PRESETS: dict[str, MissionDesign] = {
    "tiny": MissionDesign(
        name="tiny",
        area_deg=(-10.0, 20.0, -15.0, 15.0),
        samples=256,
        pixel_scale_m=(900.0, 3400.0),
        passes=4,
        spacing_factor=1.05,
        nac_fraction=0.8,
        isolated=((84.0, 200.0), (45.0, 120.0)),
        truth_dem_ppd=8.0,
        surface=SurfaceParams(crater_d_min_m=3000.0, rough_shortest_m=500.0),
        # 130 passes with nodes over lon -19..19 (the tracks lean across the area's 30 deg): >= 25
        # profiles in each of its 12 tiles (the 6 at its east and west edges are half in it), ~0.37
        # million shots; periapsis at 20 N so the equatorial area is within MLA's range.
        altimetry=AltimetryDesign(n_orbits=130, lon_range_deg=(-19.0, 19.0), periapsis_lat_deg=20.0,
                                  periapsis_alt_m=300e3),
    ),
    "demo": MissionDesign(
        name="demo",
        area_deg=None,
        samples=512,
        pixel_scale_m=(1200.0, 3200.0),
        passes=3,
        spacing_factor=0.95,
        emission_deg=(0.0, 35.0),
        nac_max_slant_m=60_000e3,
        gaps=((-35.0, 250.0, 22.0),),
        isolated=((-35.0, 250.0),),
        truth_dem_ppd=4.0,
        # Mercury's real long wavelengths: MLA's GTMES_150V05 (shipped with the package) to degree 148
        # in place of the synthetic long-wave noise and polar depression, so the demo DEM can be
        # compared with the real shape at those wavelengths (workflows/demo.yaml's reference).
        surface=with_shape_harmonics(SurfaceParams(crater_d_min_m=4000.0, rough_shortest_m=700.0),
                                     GTMES_PACKAGED, lmax=148),
        # MESSENGER-like: periapsis 400 km at 70 N, ranging within 1,000 km: ~2.7 million shots,
        # >= 20 profiles per tile north of 60 N, 6-15 at 10-60 N, none in the south.
        altimetry=AltimetryDesign(n_orbits=200, max_range_m=1_000e3),
    ),
    "large": MissionDesign(
        name="large",
        area_deg=None,
        samples=1024,
        pixel_scale_m=(70.0, 300.0),
        passes=3,
        spacing_factor=0.95,
        emission_deg=(0.0, 40.0),
        gaps=((-35.0, 250.0, 8.0), (20.0, 40.0, 5.0)),
        isolated=((-35.0, 250.0), (20.0, 40.0)),
        truth_dem_ppd=16.0,
        surface=SurfaceParams(crater_d_min_m=2000.0, rough_shortest_m=35.0, rough_hurst=0.45),
    ),
}


def get_preset(name: str) -> MissionDesign:
    """The design of a preset, or a ConfigError naming the allowed ones."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ConfigError(f"unknown synthetic mission preset {name!r}; allowed: {', '.join(PRESETS)}") from None
