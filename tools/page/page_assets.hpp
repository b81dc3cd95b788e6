// The page's HTML, script and style, compiled into the binary from tools/page/assets/ (no CDN,
// no files to install beside it).
#pragma once

#include <string_view>

namespace nccomp::page {

extern const std::string_view kIndexHtml;
extern const std::string_view kPageJs;
extern const std::string_view kPageCss;

}  // namespace nccomp::page
