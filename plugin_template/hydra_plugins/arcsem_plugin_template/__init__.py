"""Hydra discovers this SearchPathPlugin in the ``hydra_plugins`` namespace package."""
from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin


class ArcsemPluginTemplateSearchPath(SearchPathPlugin):
    """Adds this package's YAML (``backbone/constant.yaml``) to arcsem's config groups."""

    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        search_path.append(provider="arcsem-plugin-template", path="pkg://arcsem_plugin_template.conf")
