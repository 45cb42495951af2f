"""Resolution and budget profiles (TOML), installed as the package ``lite_vo.profiles``."""
