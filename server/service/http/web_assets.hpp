// The workbench's static files (client/web), embedded in riccatid at build
// time by cmake/embed_web_assets.cmake: nothing to install beside the binary,
// and nothing fetched from the internet when a page loads.
#pragma once

#include <span>
#include <string_view>

namespace riccati::service {

struct WebAsset {
  std::string_view path;          // relative to client/web: "index.html", "js/app.js"
  std::string_view content_type;
  std::string_view body;
};

std::span<const WebAsset> web_assets();

}  // namespace riccati::service
