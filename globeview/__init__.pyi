# The types of globeview's top level for type checkers (globeview/__init__.py imports these
# names lazily, by module name, so that `import globeview` stays cheap).
from globeview.app.globe import CameraPose as CameraPose
from globeview.app.globe import Globe as Globe
from globeview.app.globe import Profile as Profile
from globeview.ui.show import show as show

__version__: str
__all__: list[str]
