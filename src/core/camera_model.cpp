// Pinhole camera with radtan / equidistant distortion, read from a Kalibr camchain YAML.
//
// Distortion models (normalised coordinates x = X/Z, y = Y/Z):
//   radtan (Kalibr "radtan", OpenCV plumb_bob with k3 = 0), coefficients [k1 k2 r1 r2]:
//     r2 = x^2 + y^2, radial = 1 + k1 r2 + k2 r2^2
//     (with OpenCV's further radial terms, radial_extra = [k3 k4 k5 k6]: ROS plumb_bob's k3, rational_polynomial:
//      radial = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3))
//     xd = x radial + 2 r1 x y + r2 (r2 + 2 x^2)        (r1, r2 = tangential p1, p2)
//     yd = y radial + r1 (r2 + 2 y^2) + 2 r2 x y
//   equidistant (Kalibr "equidistant" = OpenCV fisheye), coefficients [k1 k2 k3 k4]:
//     r = |(x, y)|, theta = atan(r), theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
//     (xd, yd) = (theta_d / r) (x, y)
// The inverses are solved by Newton's method with the analytic Jacobian.
#include "diekf/camera_model.h"

#include <yaml-cpp/yaml.h>

#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace diekf {
namespace {

[[noreturn]] void fail(const std::string& path, const std::string& key, const std::string& what) {
  throw std::runtime_error(path + ": key '" + key + "': " + what);
}

double readNumber(const YAML::Node& node, const std::string& path, const std::string& key) {
  if (!node.IsScalar()) fail(path, key, "expected a number");
  double v = 0.0;
  try {
    v = node.as<double>();
  } catch (const YAML::Exception&) {
    fail(path, key, "expected a number, got '" + node.Scalar() + "'");
  }
  if (!std::isfinite(v)) fail(path, key, "expected a finite number, got '" + node.Scalar() + "'");
  return v;
}

std::vector<double> readNumbers(const YAML::Node& node, const std::string& path, const std::string& key,
                                std::size_t expected_len) {
  if (!node.IsSequence()) fail(path, key, "expected a list of " + std::to_string(expected_len) + " numbers");
  if (node.size() != expected_len) {
    fail(path, key,
         "expected " + std::to_string(expected_len) + " numbers, got " + std::to_string(node.size()));
  }
  std::vector<double> out;
  out.reserve(expected_len);
  for (std::size_t i = 0; i < node.size(); ++i) {
    out.push_back(readNumber(node[i], path, key + "[" + std::to_string(i) + "]"));
  }
  return out;
}

YAML::Node require(const YAML::Node& parent, const std::string& name, const std::string& path,
                   const std::string& key) {
  YAML::Node n = parent[name];
  if (!n || n.IsNull()) fail(path, key, "missing");
  return n;
}

std::string readString(const YAML::Node& node, const std::string& path, const std::string& key) {
  if (!node.IsScalar()) fail(path, key, "expected a string");
  return node.Scalar();
}

// Radtan distortion (with the rational radial terms `e` = k3..k6) and its Jacobian d(xd)/d(xn).
Vec2 radtan(const Vec4& k, const Vec4& e, const Vec2& p, Mat2* J) {
  const double x = p.x(), y = p.y();
  const double k1 = k[0], k2 = k[1], p1 = k[2], p2 = k[3];
  const double xx = x * x, yy = y * y, xy = x * y, r2 = xx + yy;
  const double num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * e[0]));
  const double den = 1.0 + r2 * (e[1] + r2 * (e[2] + r2 * e[3]));
  const double radial = num / den;
  const Vec2 out(x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * xx),
                 y * radial + p1 * (r2 + 2.0 * yy) + 2.0 * p2 * xy);
  if (J) {
    const double dnum = k1 + r2 * (2.0 * k2 + 3.0 * e[0] * r2);
    const double dden = e[1] + r2 * (2.0 * e[2] + 3.0 * e[3] * r2);
    const double drad = (dnum * den - num * dden) / (den * den);  // d radial / d r2
    // d radial/dx = 2x drad, d radial/dy = 2y drad
    (*J)(0, 0) = radial + 2.0 * xx * drad + 2.0 * p1 * y + 6.0 * p2 * x;
    (*J)(0, 1) = 2.0 * xy * drad + 2.0 * p1 * x + 2.0 * p2 * y;
    (*J)(1, 0) = 2.0 * xy * drad + 2.0 * p1 * x + 2.0 * p2 * y;
    (*J)(1, 1) = radial + 2.0 * yy * drad + 6.0 * p1 * y + 2.0 * p2 * x;
  }
  return out;
}

// theta_d(theta) of the equidistant model and its derivative.
double fisheyeThetaD(const Vec4& k, double th, double* dth) {
  const double t2 = th * th;
  const double poly = 1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])));
  if (dth) *dth = 1.0 + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])));
  return th * poly;
}

}  // namespace

CameraModel CameraModel::fromKalibrYaml(const std::string& path, const std::string& cam) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw std::runtime_error(path + ": cannot open the camchain file");
  } catch (const YAML::Exception& e) {
    throw std::runtime_error(path + ": cannot parse YAML: " + e.what());
  } catch (const std::exception& e) {  // e.g. a directory: the stream fails while reading
    throw std::runtime_error(path + ": cannot read the file: " + e.what());
  }
  if (!root.IsMap()) throw std::runtime_error(path + ": expected a YAML map at the top level");
  const YAML::Node c = require(root, cam, path, cam);
  if (!c.IsMap()) fail(path, cam, "expected a map");
  const std::string p = cam + "/";

  CameraModel m;
  const std::string model = readString(require(c, "camera_model", path, p + "camera_model"), path,
                                       p + "camera_model");
  if (model != "pinhole") {
    fail(path, p + "camera_model", "unsupported camera model '" + model + "' (only 'pinhole')");
  }

  const auto in = readNumbers(require(c, "intrinsics", path, p + "intrinsics"), path, p + "intrinsics", 4);
  if (!(in[0] > 0.0) || !(in[1] > 0.0)) fail(path, p + "intrinsics", "focal lengths must be positive");
  m.K.fx = in[0];
  m.K.fy = in[1];
  m.K.cx = in[2];
  m.K.cy = in[3];

  const auto res = readNumbers(require(c, "resolution", path, p + "resolution"), path, p + "resolution", 2);
  for (double r : res) {
    if (r < 1.0 || r != std::floor(r) || r > 1e6) {
      fail(path, p + "resolution", "expected two positive integers [width, height]");
    }
  }
  m.K.width = static_cast<int>(res[0]);
  m.K.height = static_cast<int>(res[1]);

  const std::string dist = readString(require(c, "distortion_model", path, p + "distortion_model"), path,
                                      p + "distortion_model");
  if (dist == "radtan" || dist == "plumb_bob") {
    m.distortion = DistortionModel::kRadTan;
  } else if (dist == "equidistant" || dist == "fisheye") {
    m.distortion = DistortionModel::kEquidistant;
  } else if (dist == "none") {
    m.distortion = DistortionModel::kNone;
  } else {
    fail(path, p + "distortion_model",
         "unsupported distortion model '" + dist + "' (radtan, equidistant or none)");
  }
  if (m.distortion != DistortionModel::kNone) {
    const auto d = readNumbers(require(c, "distortion_coeffs", path, p + "distortion_coeffs"), path,
                               p + "distortion_coeffs", 4);
    m.distortion_coeffs = Vec4(d[0], d[1], d[2], d[3]);
  } else if (c["distortion_coeffs"] && c["distortion_coeffs"].IsSequence() && c["distortion_coeffs"].size() > 0) {
    const auto d = readNumbers(c["distortion_coeffs"], path, p + "distortion_coeffs", c["distortion_coeffs"].size());
    for (double v : d) {
      if (v != 0.0) fail(path, p + "distortion_coeffs", "non-zero coefficients with distortion_model 'none'");
    }
  }

  const std::string tkey = p + "T_cam_imu";
  const YAML::Node T = require(c, "T_cam_imu", path, tkey);
  if (!T.IsSequence() || T.size() != 4) fail(path, tkey, "expected 4 rows of 4 numbers");
  Eigen::Matrix4d M;
  for (int r = 0; r < 4; ++r) {
    const auto row = readNumbers(T[r], path, tkey + "[" + std::to_string(r) + "]", 4);
    for (int k = 0; k < 4; ++k) M(r, k) = row[k];
  }
  if ((M.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff() > 1e-9) {
    fail(path, tkey, "last row must be [0, 0, 0, 1]");
  }
  const Mat3 R = M.topLeftCorner<3, 3>();
  const double orth_err = (R.transpose() * R - Mat3::Identity()).cwiseAbs().maxCoeff();
  if (orth_err > 1e-4 || R.determinant() < 0.0) {
    std::ostringstream os;
    os << "rotation block is not orthonormal with determinant +1 (max |R^T R - I| = " << orth_err
       << ", det = " << R.determinant() << ")";
    fail(path, tkey, os.str());
  }
  // Project onto SO(3) to remove the rounding of the printed values.
  const Eigen::JacobiSVD<Mat3> svd(R, Eigen::ComputeFullU | Eigen::ComputeFullV);
  m.T_cam_imu.linear() = svd.matrixU() * svd.matrixV().transpose();
  m.T_cam_imu.translation() = M.topRightCorner<3, 1>();

  if (c["timeshift_cam_imu"] && !c["timeshift_cam_imu"].IsNull()) {
    m.timeshift_cam_imu_s = readNumber(c["timeshift_cam_imu"], path, p + "timeshift_cam_imu");
  }
  if (c["line_delay_s"] && !c["line_delay_s"].IsNull()) {
    m.line_delay_s = readNumber(c["line_delay_s"], path, p + "line_delay_s");
    if (!(m.line_delay_s >= 0.0) || !(m.line_delay_s * std::max(1, m.K.height) < 0.2)) {
      std::ostringstream os;
      os << "must be a readout time per row in seconds, >= 0 and under 0.2 s for the whole frame (got "
         << m.line_delay_s << ")";
      fail(path, p + "line_delay_s", os.str());
    }
  }
  if (c["rostopic"] && !c["rostopic"].IsNull()) {
    m.rostopic = readString(c["rostopic"], path, p + "rostopic");
  }
  return m;
}

Vec2 CameraModel::distort(const Vec2& xn) const {
  switch (distortion) {
    case DistortionModel::kNone:
      return xn;
    case DistortionModel::kRadTan:
      return radtan(distortion_coeffs, radial_extra, xn, nullptr);
    case DistortionModel::kEquidistant: {
      const double r = xn.norm();
      if (r < 1e-12) return xn;  // theta_d / r -> 1
      const double th_d = fisheyeThetaD(distortion_coeffs, std::atan(r), nullptr);
      return xn * (th_d / r);
    }
  }
  return xn;
}

bool CameraModel::undistort(const Vec2& xd, Vec2* xn) const {
  constexpr int kMaxIter = 50;
  switch (distortion) {
    case DistortionModel::kNone:
      *xn = xd;
      return true;
    case DistortionModel::kRadTan: {
      // Newton on f(x) = distort(x) - xd, starting at xd; converges quadratically where the map is
      // invertible (MYNT EYE-strength coefficients over the whole image).
      Vec2 x = xd;
      for (int it = 0; it < kMaxIter; ++it) {
        Mat2 J;
        const Vec2 f = radtan(distortion_coeffs, radial_extra, x, &J) - xd;
        if (f.squaredNorm() < 1e-30) break;
        const double det = J.determinant();
        if (!std::isfinite(det) || std::abs(det) < 1e-12) return false;
        const Vec2 step = J.inverse() * f;  // 2x2, closed form
        x -= step;
        if (!x.allFinite()) return false;
        if (step.squaredNorm() < 1e-32) break;
      }
      const Vec2 f = radtan(distortion_coeffs, radial_extra, x, nullptr) - xd;
      *xn = x;
      return f.norm() < 1e-11 * (1.0 + xd.norm());
    }
    case DistortionModel::kEquidistant: {
      const double th_d = xd.norm();
      if (th_d < 1e-12) {
        *xn = xd;
        return true;
      }
      double th = th_d;  // Newton on theta_d(theta) = th_d
      for (int it = 0; it < kMaxIter; ++it) {
        double d = 0.0;
        const double f = fisheyeThetaD(distortion_coeffs, th, &d) - th_d;
        if (std::abs(f) < 1e-15) break;
        if (!(std::abs(d) > 1e-12)) return false;
        th -= f / d;
        if (!std::isfinite(th)) return false;
      }
      if (std::abs(fisheyeThetaD(distortion_coeffs, th, nullptr) - th_d) > 1e-11 * (1.0 + th_d)) return false;
      if (!(th >= 0.0) || th >= 0.5 * M_PI) return false;  // behind the camera or at infinity
      *xn = xd * (std::tan(th) / th_d);
      return true;
    }
  }
  return false;
}

bool CameraModel::project(const Vec3& p_C, Vec2* px) const {
  if (!(p_C.z() > 1e-12)) return false;
  const Vec2 xd = distort(Vec2(p_C.x() / p_C.z(), p_C.y() / p_C.z()));
  *px = Vec2(K.fx * xd.x() + K.cx, K.fy * xd.y() + K.cy);
  return px->allFinite();
}

bool CameraModel::unproject(const Vec2& px, Vec2* xn) const {
  const Vec2 xd((px.x() - K.cx) / K.fx, (px.y() - K.cy) / K.fy);
  return undistort(xd, xn);
}

}  // namespace diekf
