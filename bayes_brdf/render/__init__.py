"""The forward model R(x; theta): SVBRDF maps + views -> linear radiance images."""
from .cameras import PerspectiveCamera, RectifiedCamera
from .hits import SurfaceHits
from .lights import PointLight
from .maps import SVBRDF
from .scene import Scene
from .surface import PlanarSample
from .views import View, collocated_views, hemisphere_directions, light_stage_views, orbit_views

__all__ = [
    "SVBRDF", "PerspectiveCamera", "RectifiedCamera", "PointLight", "PlanarSample", "Scene", "SurfaceHits", "View",
    "collocated_views", "hemisphere_directions", "light_stage_views", "orbit_views",
]
