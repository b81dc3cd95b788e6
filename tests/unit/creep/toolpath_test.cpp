// The toolpath normal file parser ([creep.edge] toolpath_file).
#include "core/creep/toolpath.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>
#include <string>

namespace nccomp::core::creep {
namespace {

std::string error_of(const std::string& text) {
  try {
    (void)parse_toolpath_normals(text, "part.csv");
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

TEST(CreepToolpath, ParsesRowsCommentsAndCrlfAndNormalises) {
  const auto rows = parse_toolpath_normals(
      "# from CAM\r\npath_mm, nx, ny, nz\r\n\r\n0.0,0,0,1\r\n15,0,-0.6,0.8\r\n30,0.995,0,0\r\n",
      "part.csv");
  ASSERT_EQ(rows.size(), 3U);
  EXPECT_NEAR(rows[1].path_mm, 15.0, 0.0);
  EXPECT_NEAR(rows[1].normal[1], -0.6, 1e-12);
  EXPECT_NEAR(rows[2].normal[0], 1.0, 1e-12);  // |n| = 0.995 is normalised
}

TEST(CreepToolpath, ErrorsNameFileAndLine) {
  EXPECT_EQ(error_of("path,nx,ny,nz\n0,0,0,1\n1,0,0,1\n"),
            "part.csv:1: expected the header 'path_mm,nx,ny,nz'");
  EXPECT_EQ(error_of("path_mm,nx,ny,nz\n0,0,0,1\n1,0,0\n"),
            "part.csv:3: expected 4 columns, got 3");
  EXPECT_EQ(error_of("path_mm,nx,ny,nz\n0,0,0,1\n1,0,x,1\n"),
            "part.csv:3: ny is not a finite number: 'x'");
  EXPECT_EQ(error_of("path_mm,nx,ny,nz\n0,0,0,1\n1,0,0,nan\n"),
            "part.csv:3: nz is not a finite number: 'nan'");
  EXPECT_NE(
      error_of("path_mm,nx,ny,nz\n0,0,0,1\n1,0,0,2\n").find("part.csv:3: normal is not a unit"),
      std::string::npos);
  EXPECT_NE(error_of("path_mm,nx,ny,nz\n5,0,0,1\n5,0,0,1\n").find("part.csv:3: path_mm must be"),
            std::string::npos);
  EXPECT_EQ(error_of("path_mm,nx,ny,nz\n0,0,0,1\n"), "part.csv:3: needs at least 2 rows");
  EXPECT_EQ(error_of(""), "part.csv:1: empty file: expected the header 'path_mm,nx,ny,nz'");
  EXPECT_EQ(error_of("path_mm,nx,ny,nz\n0,0,0,1,7\n"), "part.csv:2: expected 4 columns, got 5");
}

}  // namespace
}  // namespace nccomp::core::creep
